"""``facetransfer probe``: what facetransfer sees of video files, and what it will do with them;
what a track file or a Live Link Face take holds.

    facetransfer probe VIDEO|TRACK.npz|take.csv [...] [--json]
"""

from __future__ import annotations


def register(sub) -> None:
    """Add ``facetransfer probe``."""
    p = sub.add_parser(
        "probe", help="say how videos are read (size and pixel shape, rate, fields, colour, "
        "audio, decoder) and what a track or a Live Link Face take holds",
        description="For each video: its stored and shown size, frame rate and frames (a "
        "variable rate's constant-rate timeline), interlacing, colour, audio, container and "
        "decoder, and what the commands do about each (facetransfer.io.video_facts). For a "
        "track (TRACK.npz): its frames, rate, video, model, activations and lost frames; for "
        "a take (take.csv): its rows, timecode rate and span, shapes and rotations "
        "(facetransfer.file_facts).")
    p.add_argument("videos", nargs="+", metavar="FILE",
                   help="videos, image sequences (plate/%%04d.png), tracks (.npz) or takes (.csv)")
    p.add_argument("--json", action="store_true", help="one JSON object per file, a list")
    p.set_defaults(func=run)


def _facts(path):
    """``(facts, lines)`` of one file, by its kind."""
    from ..file_facts import file_fact_lines, file_kind, take_facts, track_facts
    from ..io.video_facts import fact_lines, video_facts

    kind = file_kind(path)
    if kind == "model":
        from ..errors import FaceTransferError

        raise FaceTransferError(f"{path} is a model file, not a video: `facetransfer model info "
                                f"{path}` describes it")
    if kind == "video":
        f = video_facts(path)
        return f.as_dict(), fact_lines(f)
    f = track_facts(path) if kind == "track" else take_facts(path)
    return f, file_fact_lines(f)


def run(args) -> int:
    """Each file's facts (``--json``: a list; a file that cannot be read is an entry with its
    ``error``); then a line on stderr for each such file, the last raised (exit status 2)."""
    import json
    import sys

    facts, errors = [], []
    for v in args.videos:
        try:
            facts.append(_facts(v))
        except (ValueError, OSError) as exc:  # said below: the other files are still described
            facts.append(({"path": str(v), "error": str(exc)}, None))
            errors.append(exc)
    if args.json:
        print(json.dumps([f for f, _ in facts], indent=1))
    else:
        for _, lines in facts:
            if lines is not None:
                print("\n".join(lines))
    sys.stdout.flush()
    for exc in errors[:-1]:
        print(f"facetransfer probe: error: {exc}", file=sys.stderr)
    if errors:
        raise errors[-1]
    return 0
