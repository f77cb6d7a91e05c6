"""Fuzz every numeric option of every ``facetransfer`` command with values that make no sense.

For each command (``facetransfer --help``), each option that takes a number (its argparse
``type`` is a number's, or it holds numbers in text: ``--pose yaw=V``, ``--identity-weights``,
``--neutral``...), and each of ``0 -1 nan inf -inf 1e300 10**30 '' 1,5 1.5 abc``, one run of
the command on small inputs (:func:`audit_cli.build_fixtures`' 12-frame clip, its track and
model; a 10-frame track of the data folder's ``face_2.mp4`` with the default model where an
ARKit track is needed), in a child forked from a process that has the CLI imported (a run
that is refused costs milliseconds). Each row: exit status, lines on stderr, a traceback or
not, whether the line names the option, the last line. A row with exit status 0 is a value
taken: judge it (``1.5`` frames a second, a seed of 0, ``--max-frames 10**30`` as "at most"
are fine; a negative count, NaN or a frame numbered 10**30 are not).

    PYTHONPATH=src FACETRANSFER_DATA_DIR=... python benchmarks/fuzz_cli_numbers.py \\
        --out out/benchmarks [--only "synth-video"]

Writes ``OUT/fuzz_cli_numbers.jsonl`` and prints the rows that are not a one-line refusal
naming the option.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

VALUES = ["0", "-1", "nan", "inf", "-inf", "1e300", str(10 ** 30), "", "1,5", "1.5", "abc"]
M, C, T, A = "model.npz", "clip.mp4", "track.npz", "arkit.npz"

#: Each command's smallest run on the fixtures (the options fuzzed are added to it).
BASE = {
    "model build": ["model", "build", "--dataset", "tets/m.csv", "--out", "o.npz"],
    "model synth": ["model", "synth", M, "--out", "f.obj"],
    "model sheet": ["model", "sheet", M, "--out", "s.png"],
    "impute eval": ["impute", "eval", "--dataset", "tets/m.csv", "--out", "ie", "--trials", "1",
                    "--methods", "average", "--missing", "0.5"],
    "scan smooth": ["scan", "smooth", "tets/id0_e0.obj", "--out", "s.obj"],
    "render": ["render", M, "--out", "r.png", "--size", "64x48"],
    "synth-video": ["synth-video", "--model", M, "--random", "--frames", "3", "--size", "64x48",
                    "--out", "v.mp4"],
    "texture default": ["texture", "default", "--out", "t.png", "--size", "16"],
    "texture lift": ["texture", "lift", C, "--track", T, "--model", M, "--out", "t.png",
                     "--size", "32"],
    "texture blend": ["texture", "blend", "--source", "a.png", "--target", "b.png", "--mask",
                      "m.png", "--out", "o.png"],
    "track": ["track", C, "--model", M, "--out", "t.npz", "--passes", "1"],
    "transfer": ["transfer", "--target", C, "--target-track", T, "--expression-from", C,
                 "--source-track", T, "--model", M, "--out", "o.mp4"],
    "edit": ["edit", T, "--model", M, "--out", "e.npz"],
    "puppet": ["puppet", C, "--model", M, "--track", T, "--out", "p.mp4"],
    "demo": ["demo", "--model", M, "--source", C, "--target", C, "--out", "d"],
    "export": ["export", A, "--out", "e.csv"],
    "view": ["view", A, "--out", "v.html"],
    "batch track": ["batch", "track", C, "--model", M, "--out", "bt", "--passes", "1"],
    "batch transfer": ["batch", "transfer", "--manifest", "pairs.csv", "--model", M, "--out",
                       "btr"],
    "batch export": ["batch", "export", A, "--format", "json", "--out", "be"],
    "probe": ["probe", C],
}
#: What an option needs beside it to be reached.
EXTRA = {("track", "--crf"): ["--overlay", "ov.mp4"],
         ("track", "--start-number"): ["--overlay", "ov/%04d.png"],
         ("transfer", "--start-number"): ["--out", "seq/%04d.png"],
         ("puppet", "--start-number"): ["--out", "seq/%04d.png"],
         ("texture lift", "--k"): ["--function", "f.npz"],
         ("export", "--texture-step"): ["--format", "glb", "--texture-from", "face_2.mp4",
                                        "--out", "e.glb"],
         ("edit", "--ramp"): ["--add", "smile@0-3"]}
#: Options whose text holds a number, and where the value goes in it.
TEMPLATE = {"--add": "smile@0-{}", "--scale": "smile={}", "--identity-dials": "width={}",
            "--weights": "identity={}", "--pose": "yaw={}", "--size": "{}x48",
            "--background": "{},0,0", "--missing": "{}", "--identity": "{}",
            "--identity-weights": "{}", "--neutral": "{}", "--timecode": "{}"}


def fixtures(fx: Path) -> None:
    """:func:`audit_cli.build_fixtures`, and ``arkit.npz``: 10 frames of the data folder's
    ``face_2.mp4`` tracked with the default model (ARKit activations, for export and view)."""
    import audit_cli

    audit_cli.build_fixtures(fx)
    clip = Path(os.environ["FACETRANSFER_DATA_DIR"]) / "video" / "face_2.mp4"
    if not (fx / "face_2.mp4").exists():
        (fx / "face_2.mp4").symlink_to(clip)
    if not (fx / A).is_file():
        subprocess.run([sys.executable, "-m", "facetransfer.cli.main", "track", str(clip),
                        "--out", str(fx / A), "--max-frames", "10", "--no-progress"],
                       check=True, capture_output=True)


def _case_dir(d: Path, fx: Path) -> None:
    d.mkdir(parents=True)
    for n in (M, C, T, A, "tets", "other.mp4", "face_2.mp4"):
        (d / n).symlink_to(fx / n)
    import cv2

    for n in ("a.png", "b.png", "m.png"):
        cv2.imwrite(str(d / n), np.full((32, 32, 3), 255 if n == "m.png" else 90, np.uint8))
    (d / "pairs.csv").write_text(f"target,expression_from,target_track,source_track\n"
                                 f"{C},{C},{T},{T}\n")


def run_case(argv: list[str], d: Path, fx: Path, timeout: int) -> tuple[int, str]:
    """Exit status and stderr of ``facetransfer ARGV`` run in ``d`` by a forked child (99: a
    traceback escaped ``main``; a negative status: the signal that ended it, SIGALRM after
    ``timeout`` seconds)."""
    from facetransfer.cli.main import main

    _case_dir(d, fx)
    pid = os.fork()
    if pid == 0:                                    # the child: never returns
        os.chdir(d)
        for fd, name in ((2, "err.txt"), (1, "out.txt")):
            os.dup2(os.open(name, os.O_WRONLY | os.O_CREAT), fd)
        signal.alarm(timeout)
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:                       # noqa: BLE001 - what the audit looks for
            import traceback

            traceback.print_exc()
            code = 99
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), (d / "err.txt").read_text(errors="replace")


def _leaves(p, path):
    subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, p
    for a in subs:
        for name, sp in a.choices.items():
            yield from _leaves(sp, path + [name])


def _numeric(action) -> bool:
    """Whether an option takes a number (its type's) or text holding numbers."""
    if not action.option_strings or action.nargs == 0 or action.choices:
        return False
    kind = getattr(action.type, "__name__", None) if action.type else None
    return kind not in (None, "str", "Path", "video_out", "tracker_name", "_matte_format") or \
        action.option_strings[-1] in TEMPLATE


def cases(only: str | None = None):
    """``(command, option, value, argv)`` of every numeric option of every command."""
    from facetransfer.cli.main import build_parser

    for path, parser in _leaves(build_parser(), []):
        key = " ".join(path)
        if key not in BASE or (only and only != key):
            continue
        for a in filter(_numeric, parser._actions):
            opt = a.option_strings[-1]
            for v in VALUES:
                yield key, opt, v, BASE[key] + EXTRA.get((key, opt), []) + \
                    [opt, TEMPLATE.get(opt, "{}").format(v)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--fixtures", default=None, help="folder of built fixtures (reused)")
    ap.add_argument("--only", default=None, help="one command (e.g. 'batch track')")
    ap.add_argument("--timeout", type=int, default=60, help="seconds a run may take")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fx = Path(args.fixtures or out / "audit_fixtures").resolve()
    fixtures(fx)
    for name in ("batch", "transfer", "track", "export"):   # imported once, before the forks
        importlib.import_module(f"facetransfer.cli.{name}")

    rows = []
    with tempfile.TemporaryDirectory() as work:
        for i, (key, opt, v, argv) in enumerate(cases(args.only)):
            code, err = run_case(argv, Path(work) / f"c{i}", fx, args.timeout)
            shutil.rmtree(Path(work) / f"c{i}", ignore_errors=True)
            lines = [ln for ln in err.splitlines() if ln.strip()]
            rows.append(dict(command=key, option=opt, value=v, exit=code, lines=len(lines),
                             traceback="Traceback" in err,
                             named=any(opt in ln for ln in lines),
                             last=lines[-1] if lines else ""))
            r = rows[-1]
            if not (code == 2 and len(lines) == 1 and r["named"] and not r["traceback"]):
                print(f"{key} {opt} {v!r}: exit {code}, {len(lines)} line(s)"
                      f"{', TRACEBACK' if r['traceback'] else ''} | {r['last'][:140]}",
                      flush=True)
    (out / "fuzz_cli_numbers.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    print(f"{len(rows)} runs: {sum(r['exit'] == 0 for r in rows)} taken, "
          f"{sum(r['traceback'] for r in rows)} tracebacks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
