"""Re-run the input-and-fault audit of issue 16 against the ``facetransfer`` CLI.

Every case runs one command in a fresh folder and is judged on what a user sees and keeps:

* ``ok``: exit status 2 (or 0 where the command must succeed), no traceback, the tool's own
  ``facetransfer ...: error:`` line is the first line on stderr (no third-party log lines
  before it), and every protected file (an input, an existing output) is byte-for-byte intact and
  no temporary file is left.

Writes ``OUT/audit.json`` and ``OUT/audit.md`` (a table: case, exit status, verdict, first line).
Run it against another tree with ``PYTHONPATH=OTHER/src`` to compare (the issue's "before").

    PYTHONPATH=src FACETRANSFER_DATA_DIR=... python benchmarks/audit_cli.py --out out/benchmarks
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


@dataclass
class Case:
    name: str
    argv: list[str]
    protect: list[str] = field(default_factory=list)   # files that must survive unchanged
    expect: int = 2
    setup: object = None                                 # callable(case_dir, fixtures)
    mount: str | None = None                             # "ro" or "full": a tmpfs at case_dir/mnt
    env: dict = field(default_factory=dict)
    timeout: float = 120.0
    forbid: tuple = ()                                   # words the message must not contain
    names: str | None = None                             # a file the message must name


# ------------------------------------------------------------------------------ fixtures
def build_fixtures(d: Path) -> None:
    """model.npz (small bilinear ICT model), clip.mp4 + clip.truth.npz, track.npz, other.mp4."""
    d.mkdir(parents=True, exist_ok=True)
    # model.npz, and other.npz of other ranks (a track of model.npz given to it)
    for name, ranks in (("model.npz", {"identity": 3, "expression": 5}),
                        ("other.npz", {"identity": 2, "expression": 5})):
        if not (d / name).is_file():
            sys.path.insert(0, str(HERE.parent / "tests"))
            from conftest import QUICK_EXPRESSIONS, _quick_ict_dataset

            from facetransfer.model import build_model

            ds = _quick_ict_dataset(Path(os.environ["FACETRANSFER_DATA_DIR"]), 4,
                                    QUICK_EXPRESSIONS)
            build_model(ds, ranks).save(d / name)
    cli = [sys.executable, "-m", "facetransfer.cli.main"]
    if not (d / "clip.mp4").is_file():
        subprocess.run(cli + ["synth-video", "--model", "model.npz", "--random", "--frames", "12",
                              "--size", "320x240", "--out", "clip.mp4"], cwd=d, check=True,
                       capture_output=True)
    if not (d / "other.mp4").is_file():
        subprocess.run(cli + ["synth-video", "--model", "model.npz", "--random", "--frames", "8",
                              "--size", "240x180", "--seed", "3", "--out", "other.mp4"], cwd=d,
                       check=True, capture_output=True)
    if not (d / "track.npz").is_file():
        subprocess.run(cli + ["track", "clip.mp4", "--model", "model.npz", "--out", "track.npz",
                              "--passes", "1"], cwd=d, check=True, capture_output=True)
    if not (d / "blank.mp4").is_file():
        import cv2

        w = cv2.VideoWriter(str(d / "blank.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 25, (160, 120))
        for _ in range(5):
            w.write(np.full((120, 160, 3), 90, np.uint8))
        w.release()
    tets = d / "tets"
    if not tets.is_dir():
        tets.mkdir()
        rows = ["path,identity,expression"]
        for i in range(2):
            for e in range(2):
                name = f"id{i}_e{e}.obj"
                v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * (1 + 0.1 * i)
                v[3, 2] += 0.2 * e
                (tets / name).write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                                         + "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
                rows.append(f"{name},id{i},e{e}")
        (tets / "m.csv").write_text("\n".join(rows) + "\n")


def _link(case_dir: Path, fx: Path, *names: str) -> None:
    for n in names:
        src = fx / n
        if src.is_dir():
            shutil.copytree(src, case_dir / n)
        else:
            shutil.copy2(src, case_dir / n)


def _write(name, data):
    def setup(cd: Path, fx: Path) -> None:
        p = cd / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data(fx) if callable(data) else data)
    return setup


def _truncated(src: str, frac: float = 0.5):
    return lambda fx: (fx / src).read_bytes()[: int((fx / src).stat().st_size * frac)]


def _take(bad_row: bool = False) -> bytes:
    """A Live Link Face take of 30 rows at 30 fps (all activations 0.1); ``bad_row``: its
    third row's first value not a number."""
    sys.path.insert(0, str(HERE.parent / "src"))
    from facetransfer.export.livelink import HEADER

    rows = [",".join(HEADER)]
    for k in range(30):
        values = ["abc" if bad_row and k == 2 else "0.1"] + ["0.1"] * 60
        rows.append(f"00:00:{k // 30:02d}:{k % 30:02d}.000,61," + ",".join(values))
    return ("\n".join(rows) + "\n").encode()


def _both(*fns):
    def setup(cd, fx):
        for f in fns:
            f(cd, fx)
    return setup


def _copy(*names):
    return lambda cd, fx: _link(cd, fx, *names)


def _stale(cd: Path, fx: Path) -> None:
    _link(cd, fx, "model.npz", "clip.mp4", "track.npz")
    p = cd / ".out.999999999-abcd1234.part.npz"   # the pid of a process that is gone
    p.write_bytes(b"stale")
    os.utime(p, (1, 1))


def _symlink(cd: Path, fx: Path) -> None:
    _link(cd, fx, "model.npz", "clip.mp4", "track.npz")
    (cd / "victim.txt").write_text("precious\n")
    for name in (".out.part.npz", ".out.npz.part", ".out.tmp.npz"):
        (cd / name).symlink_to(cd / "victim.txt")


def _mediapipe_truncated(cd, fx):
    _link(cd, fx, "model.npz", "clip.mp4")
    np.savez(cd / "full.npz", landmarks=np.zeros((12, 478, 3), np.float32))
    data = (cd / "full.npz").read_bytes()
    (cd / "clip.mediapipe478.npz").write_bytes(data[: len(data) // 2])
    (cd / "full.npz").unlink()


def _bad_obj(cd, fx):
    (cd / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/5 3/1\n")


def _abc_obj(cd, fx):
    (cd / "abc.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 abc\n")


def _ragged_features(cd, fx):
    (cd / "f.json").write_text(json.dumps({"points": {str(i): [0, 1, 2] for i in range(17, 27)}
                                           | {"30": [0, 1]}}))


def _point_cloud(cd, fx):
    import trimesh

    trimesh.PointCloud(np.random.default_rng(0).normal(size=(50, 3))).export(cd / "pc.ply")
    (cd / "f.json").write_text(json.dumps({"points": {str(i): [0, 0, 0] for i in range(17, 30)}}))


def _png(cd, fx):
    import cv2

    cv2.imwrite(str(cd / "face.png"), np.zeros((8, 8, 3), np.uint8))


def _plate(gap: bool = False, suffix: str = ".png"):
    """A plate of clip.mp4's first 5 frames, plate/f.0001.png ... (frame 3 missing: ``gap``;
    another ``suffix``: files of four bytes, an OpenEXR file's magic number: damaged OpenEXR or
    DPX frames, or a format refused by name)."""
    def setup(cd, fx):
        import cv2

        (cd / "plate").mkdir()
        cap = cv2.VideoCapture(str(fx / "clip.mp4"))
        for i in range(1, 6):
            ok, bgr = cap.read()
            if gap and i == 3:
                continue
            if suffix == ".png":
                cv2.imwrite(str(cd / "plate" / f"f.{i:04d}.png"), bgr)
            else:
                (cd / "plate" / f"f.{i:04d}{suffix}").write_bytes(b"\x76\x2f\x31\x01")
        cap.release()
    return setup


def _nonmanifold(cd, fx):
    """A vertex-clustered ICT face in a smile: the fit must not refuse it."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from test_scan_repair import clustered_smile_scan   # shared with the test

    clustered_smile_scan(cd / "smile_scan.ply", cd / "smile_features.json")


def cases(fx: Path) -> list[Case]:
    M, C, T = "model.npz", "clip.mp4", "track.npz"
    c = [
        # 2. inputs destroyed
        Case("track VIDEO --out VIDEO", ["track", C, "--model", M, "--out", C],
             protect=[C], setup=_copy(M, C)),
        Case("track --overlay EXISTING.mp4", ["track", C, "--model", M, "--from-track", T,
                                              "--overlay", "other.mp4"],
             protect=["other.mp4"], setup=_copy(M, C, T, "other.mp4")),
        Case("track --out EXISTING.npz (no --overwrite)",
             ["track", C, "--model", M, "--out", "old.npz", "--passes", "1"],
             protect=["old.npz"], setup=_both(_copy(M, C), _write("old.npz", b"old track"))),
        Case("synth-video --out EXISTING.mp4", ["synth-video", "--model", M, "--random",
                                                "--frames", "2", "--out", "other.mp4"],
             protect=["other.mp4"], setup=_copy(M, "other.mp4")),
        Case("model build --dataset m.csv --out m.csv",
             ["model", "build", "--dataset", "tets/m.csv", "--out", "tets/m.csv"],
             protect=["tets/m.csv"], setup=_copy("tets")),
        # 3. / 4. temp files
        Case("planted symlink at a temp name", ["edit", T, "--model", M, "--scale", "smile=1.5",
                                                "--out", "out.npz"],
             expect=0, protect=["victim.txt"], setup=_symlink),
        Case("stale temp of a killed run removed", ["edit", T, "--model", M, "--scale",
                                                    "smile=1.5", "--out", "out.npz"],
             expect=0, setup=_stale),
        # 5. tracebacks
        Case("model build, read-only folder", ["model", "build", "--dataset", "tets/m.csv",
                                               "--out", "mnt/m.npz"], setup=_copy("tets"),
             mount="ro"),
        Case("model synth, read-only folder", ["model", "synth", M, "--out", "mnt/f.obj"],
             setup=_copy(M), mount="ro"),
        Case("render, read-only folder", ["render", M, "--out", "mnt/f.png"], setup=_copy(M),
             mount="ro"),
        Case("edit, read-only folder", ["edit", T, "--model", M, "--scale", "smile=1.5",
                                        "--out", "mnt/t.npz"], setup=_copy(M, T), mount="ro"),
        Case("track, read-only folder", ["track", C, "--model", M, "--out", "mnt/t.npz",
                                         "--passes", "1"], setup=_copy(M, C), mount="ro"),
        Case("impute eval, read-only folder", ["impute", "eval", "--dataset", "tets/m.csv",
                                               "--missing", "0.25", "--trials", "1",
                                               "--methods", "average", "--out", "mnt/ev"],
             setup=_copy("tets"), mount="ro"),
        Case("model build, full disk", ["model", "build", "--dataset", "tets/m.csv", "--out",
                                        "mnt/m.npz"], setup=_copy("tets"), mount="full"),
        Case("track, full disk", ["track", C, "--model", M, "--out", "mnt/t.npz", "--passes",
                                  "1"], setup=_copy(M, C), mount="full"),
        Case("model synth --overwrite, full disk: old file kept",
             ["model", "synth", M, "--out", "mnt/f.obj", "--overwrite"], setup=_copy(M),
             mount="full",
             protect=["mnt/f.obj"]),
        Case("track with empty T.partial.npz", ["track", C, "--model", M, "--out", "t.npz",
                                                "--passes", "1"], expect=0,
             setup=_both(_copy(M, C), _write("t.partial.npz", b""))),
        Case("track with truncated T.partial.npz", ["track", C, "--model", M, "--out",
                                                    "t.npz", "--passes", "1"], expect=0,
             setup=_both(_copy(M, C), _write("t.partial.npz", _truncated(T)))),
        Case("texture lift, truncated track", ["texture", "lift", C, "--track", "bad.npz",
                                               "--model", M, "--out", "tex.png"],
             setup=_both(_copy(M, C), _write("bad.npz", _truncated(T)))),
        Case("texture lift, empty track", ["texture", "lift", C, "--track", "bad.npz",
                                           "--model", M, "--out", "tex.png"],
             setup=_both(_copy(M, C), _write("bad.npz", b""))),
        Case("transfer --tracker landmarks, truncated NAME.mediapipe478.npz",
             ["transfer", "--target", C, "--expression-from", C, "--model", M, "--tracker",
              "landmarks", "--out", "o.mp4", "--max-frames", "3", "--no-progress"],
             setup=_mediapipe_truncated, names="clip.mediapipe478.npz"),
        Case("scan smooth, OBJ vt index out of range", ["scan", "smooth", "bad.obj", "--out",
                                                        "s.obj"], setup=_bad_obj),
        Case("demo --out EXISTING_FILE", ["demo", "--out", "file.txt", "--model", M],
             protect=["file.txt"], setup=_both(_copy(M), _write("file.txt", b"keep"))),
        # 6. bounds
        Case("model build --identities 100000", ["model", "build", "--dataset", "ict-bilinear",
                                                 "--identities", "100000", "--out", "m.npz"],
             env={"__ULIMIT_KB": "6000000"}, timeout=120),
        Case("edit --scale smile=1e308", ["edit", T, "--model", M, "--scale", "smile=1e308",
                                          "--out", "o.npz"], setup=_copy(M, T)),
        Case("puppet with another video's track", ["puppet", "other.mp4", "--model", M,
                                                   "--identity", "id01", "--track", T,
                                                   "--out", "p.mp4"],
             setup=_copy(M, T, "other.mp4")),
        Case("model sheet --max-identities -1", ["model", "sheet", M, "--out", "s.png",
                                                 "--max-identities", "-1"], setup=_copy(M)),
        # 7. messages
        Case("OBJ face index 'abc'", ["scan", "smooth", "abc.obj", "--out", "s.obj"],
             setup=_abc_obj, forbid=("invalid literal",), names="abc.obj"),
        Case("ragged feature points", ["scan", "fit", "bad.obj", "--features", "f.json",
                                       "--out", "fit.obj"],
             setup=_both(_bad_obj, _ragged_features), forbid=("inhomogeneous",),
             names="f.json"),
        Case("scan fit on a point cloud", ["scan", "fit", "pc.ply", "--features", "f.json",
                                           "--out", "fit.obj"], setup=_point_cloud,
             forbid=("PointCloud", "no vertices"), names="pc.ply"),
        Case("a PNG passed as a model", ["model", "info", "face.png"], setup=_png,
             forbid=("allow_pickle", "pickle"), names="face.png"),
        Case("a folder passed as a model", ["model", "info", "."], forbid=("does not exist",)),
        Case("a folder passed as a video", ["probe", "."], forbid=("does not exist",)),
        Case("a track passed as a video", ["track", T, "--model", M, "--out", "t2.npz"],
             setup=_copy(M, T), names=T, forbid=("OpenCV",)),
        Case("a plate with a missing frame", ["probe", "plate/f.####.png"],
             setup=_plate(gap=True), names="f.0003.png"),
        Case("a damaged OpenEXR plate", ["probe", "plate/f.%04d.exr"],
             setup=_plate(suffix=".exr"), names="plate/f.0001.exr"),
        Case("a damaged DPX plate", ["probe", "plate/f.%04d.dpx"], setup=_plate(suffix=".dpx"),
             names="plate/f.0001.dpx"),
        Case("a Cineon plate", ["probe", "plate/f.%04d.cin"], setup=_plate(suffix=".cin"),
             names="plate/f.%04d.cin"),
        Case("an overlay written over the plate it tracks",
             ["track", "plate/f.####.png", "--model", M, "--out", "t.npz", "--overlay",
              "plate/f.%04d.png", "--overwrite"], setup=_both(_copy(M), _plate()),
             protect=["plate/f.0001.png", "plate/f.0005.png"], names="plate/f.####.png"),
        Case("a plate's folder passed as a video", ["probe", "plate"], setup=_plate(),
             names="plate/f.%04d.png"),
        Case("a folder passed as a track", ["edit", ".", "--model", M, "--scale", "smile=2",
                                            "--out", "o.npz"], setup=_copy(M), forbid=("does not exist",)),
        Case("a take with a damaged row", ["transfer", "--target", C, "--expression-from",
                                           "take.csv", "--model", M, "--out", "o.mp4"],
             setup=_both(_copy(M, C), _write("take.csv", _take(bad_row=True))),
             names="take.csv"),
        Case("a take for a model without ARKit expressions",
             ["transfer", "--target", C, "--expression-from", "take.csv", "--model", M,
              "--out", "o.mp4"], setup=_both(_copy(M, C), _write("take.csv", _take())),
             names="take.csv"),
        Case("a take with --pose-from", ["transfer", "--target", C, "--expression-from",
                                         "take.csv", "--pose-from", C, "--model", M, "--out",
                                         "o.mp4"],
             setup=_both(_copy(M, C), _write("take.csv", _take())), names="take.csv"),
        Case("export --timecode not a timecode", ["export", T, "--format", "livelink",
                                                  "--timecode", "10:00", "--out", "t.csv"],
             setup=_copy(T), forbid=("Traceback",)),
        Case("a required option missing (transfer without --target)",
             ["transfer", "--expression-from", C, "--out", "o.mp4"], setup=_copy(C)),
        Case("an option's value not among its choices (--codec vp9)",
             ["transfer", "--target", C, "--out", "o.mp4", "--codec", "vp9"], setup=_copy(C)),
        Case("a track named as a video (track --out t.mp4)",
             ["track", C, "--model", M, "--out", "t.mp4"], setup=_copy(M, C),
             names="t.mp4"),
        Case("a glb export named .usd", ["export", T, "--format", "glb", "--out", "f.usd"],
             setup=_copy(T), names="f.usd"),
        # the thirty-eighth session's walk
        Case("a fitted mesh named .csv (scan fit --out fit.csv)",
             ["scan", "fit", "bad.obj", "--features", "f.json", "--out", "fit.csv"],
             setup=_both(_bad_obj, _ragged_features), names="fit.csv",
             forbid=("exporter not available",)),
        Case("an option the command does not take (edit --bogus)",
             ["edit", T, "--model", M, "--bogus", "1", "--out", "e.npz"], setup=_copy(M, T),
             names="facetransfer edit --help"),
        Case("a track of another model (export --model)",
             ["export", T, "--model", "other.npz", "--out", "t.csv"],
             setup=_copy(T, "other.npz"),
             names=T, forbid=("must end in",)),
        Case("puppet, read-only folder (refused before the render)",
             ["puppet", C, "--model", M, "--max-frames", "3", "--out", "mnt/p.mp4"],
             setup=_copy(M, C), mount="ro"),
        Case("third-party log lines before the tool's line (no face)",
             ["track", "blank.mp4", "--model", M, "--out", "t.npz"], setup=_copy(M, "blank.mp4")),
        Case("transfer --meshes in a read-only folder (refused before the render)",
             ["transfer", "--target", C, "--target-track", T, "--expression-from", C,
              "--source-track", T, "--model", M, "--meshes", "mnt/m", "--out", "t.mp4"],
             setup=_copy(M, C, T), mount="ro", names="--meshes"),
        Case("a take given as --performance",
             ["transfer", "--target", C, "--target-track", T, "--performance", "take.csv",
              "--model", M, "--out", "t.mp4"],
             setup=_both(_copy(M, C, T), _write("take.csv", _take())), names="--expression-from"),
        Case("track --smooth out of range", ["track", C, "--model", M, "--smooth", "1e9",
                                             "--out", "t.npz"], setup=_copy(M, C),
             names="--smooth", forbid=("memory",)),
        # 8. raw scans
        Case("scan fit on a vertex-clustered non-manifold smiling scan",
             ["scan", "fit", "smile_scan.ply", "--features", "smile_features.json", "--out",
              "fit.obj", "--no-progress"], expect=0, setup=_nonmanifold, timeout=300),
    ]
    return c


# ------------------------------------------------------------------------------ running
def _digest(p: Path) -> str | None:
    return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None


@contextlib.contextmanager
def _mounted(path: Path, kind: str | None):
    if kind is None:
        yield
        return
    path.mkdir(exist_ok=True)
    if kind == "full":   # a tiny tmpfs: any output fills it
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(path)], check=True)
        (path / "f.obj").write_text("v 0 0 0\n# old good file\n")
        with contextlib.suppress(OSError):
            (path / "filler").write_bytes(b"x" * 12000)
    else:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=16k", "tmpfs", str(path)],
                       check=True)
    try:
        yield
    finally:
        subprocess.run(["umount", str(path)], check=False)


def _temps(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*")
                  if ".part" in p.name and not p.is_symlink())


def run_case(case: Case, fx: Path, work: Path) -> dict:
    cd = work / case.name.replace(" ", "_").replace("/", "_")[:60]
    cd.mkdir(parents=True)
    if case.setup is not None:
        case.setup(cd, fx)
    env = dict(os.environ)
    env.update({k: v for k, v in case.env.items() if not k.startswith("__")})
    cmd = [sys.executable, "-m", "facetransfer.cli.main"] + case.argv
    if "__ULIMIT_KB" in case.env:
        cmd = ["bash", "-c", f"ulimit -v {case.env['__ULIMIT_KB']}; exec \"$@\"", "_"] + cmd
    with _mounted(cd / "mnt", case.mount):
        before = {p: _digest(cd / p) for p in case.protect}
        try:
            r = subprocess.run(cmd, cwd=cd, env=env, capture_output=True, text=True,
                               timeout=case.timeout)
            rc, err = r.returncode, r.stderr
        except subprocess.TimeoutExpired as exc:
            rc, err = "timeout", (exc.stderr or b"").decode(errors="replace")
        after = {p: _digest(cd / p) for p in case.protect}
        temps = _temps(cd)
    progress = re.compile(r"\[\d+:\d+(?:<|,)")   # a tqdm bar ("| 3/16 [00:00<00:01, ...]")
    lines = [ln for ln in err.replace("\r", "\n").splitlines()
             if ln.strip() and not progress.search(ln)]
    tb = "Traceback (most recent call last)" in err
    own = [i for i, ln in enumerate(lines) if ln.startswith("facetransfer ")]
    first_own = own[0] if own else None
    reasons = []
    if rc != case.expect:
        reasons.append(f"exit {rc}, expected {case.expect}")
    if tb:
        reasons.append("traceback")
    if case.expect == 2 and first_own is None:
        reasons.append("no facetransfer error line")
    if case.expect == 2 and first_own:
        reasons.append(f"{first_own} other line(s) before it")
    lost = [p for p in case.protect if before[p] != after[p]]
    if lost:
        reasons.append("destroyed " + ", ".join(lost))
    if temps:
        reasons.append("left " + ", ".join(temps))
    msg = lines[first_own] if first_own is not None else ""
    for w in case.forbid:
        if w in msg:
            reasons.append(f"says {w!r}")
    if case.names and case.names not in msg:
        reasons.append(f"does not name {case.names}")
    shown = lines[first_own] if first_own is not None else (lines[-1] if lines else "")
    return {"case": case.name, "command": "facetransfer " + " ".join(case.argv), "exit": rc,
            "ok": not reasons, "problems": reasons, "line": shown[:220]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--fixtures", default=None, help="folder of built fixtures (reused)")
    ap.add_argument("--label", default="after", help="name of this run in the output files")
    ap.add_argument("--only", default=None, help="run cases whose name contains this text")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fx = Path(args.fixtures or out / "audit_fixtures").resolve()
    build_fixtures(fx)
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for case in cases(fx):
            if args.only and args.only not in case.name:
                continue
            row = run_case(case, fx, Path(work))
            rows.append(row)
            print(f"{'ok ' if row['ok'] else 'BAD'} {row['case']}: {row['exit']} "
                  f"{'; '.join(row['problems'])} | {row['line']}", flush=True)
    (out / f"audit_{args.label}.json").write_text(json.dumps(rows, indent=1) + "\n")
    md = ["| case | exit | verdict | first line |", "|---|---|---|---|"]
    for r in rows:
        verdict = "ok" if r["ok"] else "; ".join(r["problems"])
        md.append(f"| {r['case']} | {r['exit']} | {verdict} | {r['line'].replace('|', '/')} |")
    (out / f"audit_{args.label}.md").write_text("\n".join(md) + "\n")
    n_ok = sum(r["ok"] for r in rows)
    print(f"{n_ok} of {len(rows)} cases ok; wrote {out / f'audit_{args.label}.md'}")
    runs = {lab: json.loads((out / f"audit_{lab}.json").read_text())
            for lab in ("before", "after") if (out / f"audit_{lab}.json").is_file()}
    if len(runs) == 2:
        plot(runs, out / "audit.png")
        print(f"wrote {out / 'audit.png'}")
    return 0


def plot(runs: dict, path: Path) -> None:
    """One row per case, a cell per run: green ok, red not (the problem written in it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["case"] for r in runs["after"]]
    fig, ax = plt.subplots(figsize=(13, 0.32 * len(names) + 1.2))
    for j, (lab, rows) in enumerate(runs.items()):
        by = {r["case"]: r for r in rows}
        for i, n in enumerate(names):
            r = by.get(n)
            ok = bool(r and r["ok"])
            ax.add_patch(plt.Rectangle((j, i), 0.98, 0.9, color="#4caf50" if ok else "#e53935"))
            text = "ok" if ok else ("; ".join(r["problems"]) if r else "not run")
            ax.text(j + 0.02, i + 0.45, text[:70], va="center", fontsize=6, color="white")
    ax.set_xlim(0, len(runs))
    ax.set_ylim(len(names), 0)
    ax.set_yticks([i + 0.45 for i in range(len(names))], names, fontsize=7)
    ax.set_xticks([j + 0.5 for j in range(len(runs))],
                  [f"{lab}: {sum(r['ok'] for r in rows)}/{len(rows)} ok"
                   for lab, rows in runs.items()])
    ax.xaxis.tick_top()
    ax.set_title("facetransfer CLI audit (issue 16): bad inputs and faults", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
