"""README.md against the program: every command line it shows names a real subcommand and only
options that subcommand's parser takes (with a value among its choices where it lists them), and
every key its "Track file" table lists is written by a real track. So README cannot drift from
the CLI again without a test failing."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from facetransfer.cli.main import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"

#: An option as README writes it: ``--name`` or ``--name=value``, or ``-v``.
_OPTION = re.compile(r"^(--[a-z][a-z0-9-]*|-[a-zA-Z])(?:=.*)?$")


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Every parser below ``parser`` by its words (``"model synth"``, ``"track"``)."""
    found = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found[name] = sub
                found.update({f"{name} {k}": p for k, p in _subcommands(sub).items()})
    return found


def _fenced_lines(text: str) -> list[str]:
    """The command lines of README's fenced blocks: ``\\``-continued and indented-``[`` lines
    joined, a ``$ `` prompt and ``#`` comments removed."""
    lines = []
    for block in re.findall(r"^```[a-z]*\n(.*?)^```", text, flags=re.S | re.M):
        for raw in block.splitlines():
            line = re.sub(r"\s#\s.*$", "", raw).rstrip()
            line = line[2:] if line.startswith("$ ") else line
            if lines and (lines[-1].endswith("\\") or re.match(r"^\s+\[", line)):
                lines[-1] = lines[-1].rstrip("\\") + " " + line.strip()
            elif line.strip():
                lines.append(line.strip())
    return lines


def _inline_spans(text: str) -> list[str]:
    """README's inline code spans (outside fenced blocks)."""
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return [s.replace("\\|", "|") for s in re.findall(r"`([^`\n]+)`", prose)]


def readme_commands() -> list[tuple[str, list[str]]]:
    """Each command README shows, as (the subcommand's words, the tokens after them).

    A command is a fenced line or an inline span that starts with ``facetransfer`` or with a
    subcommand's words (``track --face right``, ``model synth --face FACE.json``); what follows
    ``facetransfer`` before the subcommand (``-v``) is the top-level parser's."""
    subs = _subcommands(build_parser())
    text = README.read_text()
    found = []
    for snippet in _fenced_lines(text) + _inline_spans(text):
        for part in re.split(r";\s*|\s\|\s(?=facetransfer )", snippet):
            words = part.split()
            if words and words[0] == "facetransfer":
                words = words[1:]
                while words and words[0].startswith("-"):
                    found.append(("", [words.pop(0)]))
            elif not words or words[0] not in subs:
                continue
            if not words or words[0] not in subs:
                continue
            name = " ".join(words[:2]) if " ".join(words[:2]) in subs else words[0]
            found.append((name, words[len(name.split()):]))
    return found


def _option_problems(name: str, tokens: list[str], parser) -> list[str]:
    """What is wrong with ``tokens`` as options of ``parser`` (unknown option, value not among
    its choices)."""
    problems = []
    actions = parser._option_string_actions
    for i, token in enumerate(tokens):
        m = _OPTION.match(token)
        if not m:
            continue
        option = m.group(1)
        if option not in actions:
            problems.append(f"facetransfer {name} {option}: no such option")
            continue
        choices = actions[option].choices
        value = token.split("=", 1)[1] if "=" in token else (
            tokens[i + 1] if i + 1 < len(tokens) else "")
        if choices and value and not value.startswith("-") and re.fullmatch(r"[a-z0-9|_-]+",
                                                                             value):
            problems += [f"facetransfer {name} {option} {v}: not among {list(choices)}"
                         for v in value.split("|") if v not in choices]
    return problems


def test_readme_shows_commands():
    """The extraction finds README's commands (so the next test is not vacuous)."""
    names = {n for n, _ in readme_commands()}
    assert {"track", "transfer", "export", "batch track", "model synth", "probe"} <= names


def test_every_option_readme_names_is_taken_by_its_subcommand():
    parser = build_parser()
    subs = _subcommands(parser)
    problems = []
    for name, tokens in readme_commands():
        problems += _option_problems(name, tokens, subs[name] if name else parser)
    assert not problems, "README names:\n" + "\n".join(sorted(set(problems)))


def test_the_checker_catches_an_option_that_does_not_exist():
    subs = _subcommands(build_parser())
    assert _option_problems("track", ["V.mp4", "--out", "T.npz", "--max-frames", "3"],
                            subs["track"]) == []
    assert _option_problems("track", ["V.mp4", "--frames", "3"], subs["track"]) == [
        "facetransfer track --frames: no such option"]
    assert _option_problems("transfer", ["--speed", "fast|turbo"], subs["transfer"]) == [
        "facetransfer transfer --speed turbo: not among ['fast', 'balanced', 'quality']"]


def _track_table_keys() -> set[str]:
    """The keys README's "Track file (`TRACK.npz`)" table lists."""
    text = README.read_text()
    section = text.split("### Track file (`TRACK.npz`)", 1)[1].split("\n### ", 1)[0]
    keys = set()
    for row in re.findall(r"^\| (.*?) \|", section, flags=re.M):
        keys |= set(re.findall(r"`([^`]+)`", row))
    return keys


def _full_track(n: int = 4):
    """A track with every optional part (ARKit activations, detections, two shots, non-square
    pixels, the clip's numbering, the covered regions), as a capture of an edited anamorphic
    clip makes it (``track --occluders``), marked as a transfer's saved performance (``made_by``)."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.io.source_facts import SourceFacts
    from facetransfer.track.result import Track

    return Track(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.ones(n), translation=np.zeros((n, 2)),
                 weights={"identity": np.zeros((n, 3)), "expression": np.zeros((n, 52))},
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash="0" * 64,
                 mode_names=("identity", "expression"), source="clip.mp4",
                 blendshapes=np.zeros((n, 52), np.float32), blendshape_names=ARKIT_NAMES,
                 detections2d=np.zeros((n, 68, 2)), pixel_aspect=0.9375, shot_starts=(2,),
                 source_facts=SourceFacts(1001, "01:00:00:00"),
                 occluded=np.zeros((n, 3), bool), made_by="transfer")


def test_the_track_file_table_lists_exactly_the_keys_a_track_writes(tmp_path):
    """Track.save (what every tracker and ``facetransfer track`` write through) of a track
    with every optional part: README's table names each key it writes and no other."""
    written = set(np.load(_full_track().save(tmp_path / "t.npz")).files)
    listed = _track_table_keys()
    modes = {k for k in written if k.startswith("weights_")}
    assert modes == {"weights_identity", "weights_expression"}
    assert "weights_<mode>" in listed
    assert listed - {"weights_<mode>"} == written - modes, (
        f"README lists {sorted(listed - written - {'weights_<mode>'})} that a track does not "
        f"write; a track writes {sorted(written - modes - listed)} that README does not list")


def test_the_batch_summary_and_manifest_columns_are_those_readme_names():
    from facetransfer.batch.manifest import CLIP_COLUMNS, PAIR_PATH_COLUMNS, PAIR_VALUE_COLUMNS
    from facetransfer.batch.summary import STATUSES, SUMMARY_COLUMNS

    text = " ".join(README.read_text().split())
    said = re.search(r"`DIR/summary.csv`: `([^`]+)`", text).group(1)
    assert re.sub(r" \([^)]*\)", "", said).split(", ") == list(SUMMARY_COLUMNS)
    assert re.search(r"status \(([^)]*)\)", said).group(1).split(", ") == list(STATUSES)
    manifests = text.split("- **Manifests**", 1)[1].split("- **Failures", 1)[0]
    named = set(re.findall(r"`([a-z_]+)`", manifests))
    assert set(CLIP_COLUMNS) | set(PAIR_PATH_COLUMNS) | set(PAIR_VALUE_COLUMNS) <= named
