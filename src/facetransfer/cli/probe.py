"""``facetransfer probe``: what facetransfer sees of video files, and what it will do with them.

    facetransfer probe VIDEO [VIDEO ...] [--json]
"""

from __future__ import annotations


def register(sub) -> None:
    """Add ``facetransfer probe``."""
    p = sub.add_parser(
        "probe", help="say how videos are read: size and pixel shape, rate, fields, colour, "
        "audio, decoder",
        description="For each video: its stored and shown size, frame rate and frames (a "
        "variable rate's constant-rate timeline), interlacing, colour, audio, container and "
        "decoder, and what the commands do about each (facetransfer.io.video_facts).")
    p.add_argument("videos", nargs="+", metavar="VIDEO")
    p.add_argument("--json", action="store_true", help="one JSON object per video, a list")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from ..io.video_facts import fact_lines, video_facts

    facts = [video_facts(v) for v in args.videos]     # every file checked before any output
    if args.json:
        print(json.dumps([f.as_dict() for f in facts], indent=1))
        return 0
    for f in facts:
        print("\n".join(fact_lines(f)))
    return 0
