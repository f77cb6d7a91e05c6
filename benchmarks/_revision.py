"""Another revision of this repository's ``src``, for benchmarks that run two trees in turn.

:func:`extract_src` writes a git revision's ``src`` folder to a temporary folder (``git
archive``); a benchmark then runs its worker in a fresh process with that folder first on
``PYTHONPATH`` (``bench_rewrite_frame.py``, ``bench_jaw_seam.py``), or the command itself
(:func:`run_command`: ``bench_plate_header.py``, ``bench_primaries.py``). A worker calls the
library through :func:`rewrite_plan` and :func:`hard_paste`, which call it as the tree on the
path, older or newer, takes it. :func:`add_base_options` and :func:`base_src` give a benchmark
the ``--base SRC`` / ``--base-rev REV`` options (``bench_rewrite_frame.py``,
``bench_track_pair.py``); :func:`now_and_before` its ``--before REV`` command line.
"""

from __future__ import annotations

import atexit
import io
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path


def extract_src(rev: str, prefix: str = "bench_") -> Path:
    """The ``src`` folder of git revision ``rev`` of this repository, in a new temporary folder
    whose name starts with ``prefix``, removed when this process exits (before, every run of a
    benchmark left its ~12 MB tree in the temporary folder)."""
    repo = Path(__file__).resolve().parents[1]
    tmp = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    tar = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", rev, "src"],
                         check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(tmp, filter="data")
    return tmp / "src"


def add_base_options(ap) -> None:
    """``--base`` (a ``src`` folder) and ``--base-rev`` (a git revision) on the argument parser
    ``ap``: the tree a benchmark compares this one with (:func:`base_src`)."""
    ap.add_argument("--base", help="the src folder of the revision to compare with")
    ap.add_argument("--base-rev", help="or a git revision of this repository (e.g. main), "
                    "extracted to a temporary folder")


def base_src(args, prefix: str) -> Path | None:
    """The ``src`` folder :func:`add_base_options`' options name (``--base-rev`` extracted by
    :func:`extract_src` into a folder named from ``prefix``), or None (neither given)."""
    if args.base:
        return Path(args.base)
    return extract_src(args.base_rev, prefix) if args.base_rev else None


def rewrite_plan(plan, model, options, *, workers: int = 1, **more):
    """The frames of a ``TransferPlan`` rewritten (``rewrite_frames``, its mouth from the plan's
    mouth source) by the tree on the path: one with ``MouthSource`` and ``RenderRun``, or one
    before them (the mouth's and the run's keywords loose; ``rewrite_frames`` in
    ``rewrite.py`` before ``rewrite_clip.py``); ``more``: keywords of this tree's (``matte``)."""
    try:
        from facetransfer.rewrite_clip import MouthSource, RenderRun, rewrite_frames
    except ImportError:
        try:
            from facetransfer.rewrite_clip import rewrite_frames
        except ImportError:
            from facetransfer.rewrite import rewrite_frames
        return rewrite_frames(plan.target_frames, plan.target_track, plan.new_track, model,
                              source_frames=plan.mouth_frames, source_track=plan.mouth_track,
                              source_index=plan.mouth_index, options=options, workers=workers)
    return rewrite_frames(plan.target_frames, plan.target_track, plan.new_track, model,
                          mouth_source=MouthSource(plan.mouth_frames, plan.mouth_track,
                                                   plan.mouth_index),
                          options=options, run=RenderRun(workers=workers), **more)


def hard_paste():
    """``paste(frame, V, camera, topo, face_texture) -> RewriteFrame``: ``rewrite_frame`` with
    a hard paste (no blend), by the tree on the path: one with ``FrameTextures`` and
    ``BlendOptions``, or one before them (the face texture bare, ``blend="none"``)."""
    from facetransfer.rewrite import rewrite_frame
    try:
        from facetransfer.rewrite import FrameTextures
        from facetransfer.rewrite_options import BlendOptions
    except ImportError:
        return lambda frame, V, c, topo, tex: rewrite_frame(frame, V, c, topo, tex, blend="none")
    return lambda frame, V, c, topo, tex: rewrite_frame(frame, V, c, topo, FrameTextures(tex),
                                                        blending=BlendOptions("none"))


def run_command(args: list, src: Path | None = None) -> tuple[int, str]:
    """``facetransfer ARGS --no-progress`` in a fresh process, by this environment's tree or
    by the tree ``src`` (:func:`extract_src`); its exit status and its error output's end."""
    env = dict(os.environ)
    cmd = [str(Path(sys.executable).parent / "facetransfer")]
    if src is not None:
        env["PYTHONPATH"] = str(src)
        cmd = [sys.executable, "-c", "import sys; from facetransfer.cli.main import main; "
               "sys.exit(main())"]
    run = subprocess.run(cmd + [str(a) for a in args] + ["--no-progress"], capture_output=True,
                         text=True, env=env)
    return run.returncode, run.stderr.strip()[-300:]


def now_and_before(doc: str, before: str) -> tuple[Path, dict, str]:
    """The command line of a benchmark that runs this tree and the revision ``--before``
    (default ``before``) in turn: ``(--out, created; {"now": None, "before": its src};
    the revision)``, its description the first line of ``doc``."""
    from _report import arguments

    ap = arguments(doc)
    ap.add_argument("--before", default=before, help="the revision run beside this tree")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out, {"now": None, "before": extract_src(args.before)}, args.before
