"""The CLI's side of issue 16: one output rule for every command, bounds checked before any work,
one line for OS errors, and native libraries' log lines kept off stderr."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from facetransfer.cli.main import error_line, main

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _err(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


# ------------------------------------------------------------------------------ one output rule
@pytest.fixture
def tiny_model(tmp_path):
    from facetransfer.datasets import FaceDataset
    from facetransfer.model import build_model

    rng = np.random.default_rng(0)
    ds = FaceDataset(rng.normal(size=(2, 2, 6, 3)), np.ones((2, 2), bool),
                     ("identity", "expression"), (("a", "b"), ("n", "s")),
                     np.array([[0, 1, 2], [2, 3, 4], [3, 4, 5]]), None, None, None, {})
    p = tmp_path / "m.npz"
    build_model(ds, {"identity": 2, "expression": 2}).save(p)
    return p


def test_existing_output_needs_overwrite(tiny_model, tmp_path, capsys):
    out = tmp_path / "face.obj"
    out.write_text("old\n")
    assert main(["model", "synth", str(tiny_model), "--out", str(out)]) == 2
    assert _err(capsys) == [f"facetransfer model synth: error: output {out} exists; pass --overwrite "
                            "to replace it"]
    assert out.read_text() == "old\n"
    assert main(["model", "synth", str(tiny_model), "--out", str(out), "--overwrite"]) == 0
    assert out.read_text().startswith("# written by facetransfer")


def test_output_that_is_an_input_is_refused(tmp_path, capsys):
    mesh = tmp_path / "scan.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    before = mesh.read_bytes()
    link = tmp_path / "alias.obj"
    link.symlink_to(mesh)
    for out in (mesh, link):   # the same path, or the same file through a link
        assert main(["scan", "smooth", str(mesh), "--out", str(out), "--overwrite"]) == 2
        assert _err(capsys) == [f"facetransfer scan smooth: error: output {out} is also an input "
                                f"({mesh}); choose another output name"]
    assert mesh.read_bytes() == before and link.is_symlink()


def test_track_out_is_the_video_is_refused(tiny_model, tmp_path, capsys):
    video = tmp_path / "v.mp4"
    video.write_bytes(b"not really a video")
    assert main(["track", str(video), "--model", str(tiny_model), "--out", str(video),
                 "--overwrite"]) == 2
    assert "is also an input" in _err(capsys)[0] and video.read_bytes() == b"not really a video"


def test_bounds_are_checked_before_any_work(tiny_model, tmp_path, capsys, monkeypatch):
    from facetransfer.cli import model as cli_model

    assert main(["model", "sheet", str(tiny_model), "--out", str(tmp_path / "s.png"),
                 "--max-identities", "-1"]) == 2
    assert "--max-identities must be >= 1" in _err(capsys)[0]
    monkeypatch.setattr(cli_model, "available_memory", lambda: 1 << 30)   # 1 GiB
    assert main(["model", "build", "--dataset", "ict-bilinear", "--identities", "2000",
                 "--out", str(tmp_path / "big.npz")]) == 2
    line = _err(capsys)[0]
    # 2000 x 10 cells x 9409 vertices x 3 x 8 bytes x 4 copies = 16.8 GiB
    assert "needs about 16.8 GiB" in line and "1.0 GiB available" in line
    assert cli_model.build_memory_estimate("ict-bilinear", None) == 4 * 15 * 10 * 9409 * 3 * 8


# ------------------------------------------------------------------------------ one line
def test_error_line_for_os_errors():
    e = OSError(errno.ENOSPC, "No space left on device")
    assert error_line("x", e) == "facetransfer x: error: no space left on the device"
    e = PermissionError(errno.EACCES, "Permission denied", "/data/out")
    assert error_line("x", e) == "facetransfer x: error: Permission denied: /data/out"
    assert "out of memory" in error_line("x", MemoryError())


@pytest.mark.parametrize("argv, says", [
    (["transfer", "--out", "r.mp4"], "facetransfer transfer: error: the following arguments "
     "are required: --target (options: facetransfer transfer --help)"),
    (["transfer", "--target", "t.mp4", "--out", "r.mp4", "--codec", "vp9"],
     "facetransfer transfer: error: argument --codec: invalid choice: 'vp9' (choose from "
     "'h264', 'h265', 'prores') (options: facetransfer transfer --help)"),
    (["model", "build", "--out", "m.npz"], "facetransfer model build: error: the following "
     "arguments are required: --dataset (options: facetransfer model build --help)"),
    (["track", "v.mp4", "--sequence-fps", "0"], "facetransfer track: error: argument "
     "--sequence-fps: expected a frame rate in (0, 1000], got '0' (options: facetransfer "
     "track --help)"),
    (["track", "v.mp4", "--bogus"], "facetransfer track: error: unrecognized arguments: "
     "--bogus (options: facetransfer track --help)"),
    (["-v", "model", "synth", "--out", "a.obj", "--zz"], "facetransfer model synth: "
     "error: unrecognized arguments: --zz (options: facetransfer model synth --help)"),
    (["--bogus"], "facetransfer: error: unrecognized arguments: --bogus (options: "
     "facetransfer --help)"),
])
def test_usage_errors_are_one_line(argv, says, capsys):
    """A usage error is the one line that says what is wrong, not the command's whole usage
    (25 lines for transfer) with the line at its end; exit status 2."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [says] and captured.out == ""


@pytest.mark.parametrize("argv, says", [
    (["track", "clip.mp4", "--out", "t.mp4"], "--out t.mp4: a track is written as .npz, not "
     ".mp4; name it t.npz (--overlay writes a video of the fitted mesh over the clip)"),
    (["edit", "t.npz", "--scale", "jawOpen=2", "--out", "e"], "--out e: a track is written "
     "as .npz, and the name has no extension; name it e.npz"),
    (["edit", "t.npz", "--add", "jawOpen@1-2", "--ramp", "-3", "--out", "e.npz"],
     "--ramp must be >= 0 frames, got -3"),
    (["model", "build", "--dataset", "ict-bilinear", "--out", "m.obj"], "--out m.obj: a model "
     "is written as .npz, not .obj; name it m.npz"),
    (["view", "t.npz", "--out", "page.npz"], "--out page.npz: the dial editor's page is "
     "written as .html or .htm, not .npz; name it page.html"),
    (["export", "t.npz", "--format", "glb", "--out", "face.usd"], "output face.usd: a glb "
     "export is written as .glb, not .usd; name it face.glb (or --format usd)"),
    (["export", "t.npz", "--format", "livelink", "--out", "take.glb"], "output take.glb: a "
     "livelink export is written as .csv, not .glb; name it take.csv (or --format glb)"),
    (["export", "t.npz", "--out", "face.fbx"], "cannot tell the export format of face.fbx from "
     "its extension: name it .csv (livelink), .glb (glb), .usd, .usda or .usdc (usd), .json "
     "(json), or give --format"),
    (["scan", "features", "s.obj", "--out", "f.png"], "--out f.png: a feature-point file is "
     "written as .json, not .png; name it f.json"),
    (["scan", "features", "s.obj", "--out", "f.json", "--picture", "h.txt"], "--picture "
     "h.txt: the picture of the points is written as .png, .jpg or .jpeg, not .txt; name it "
     "h.png"),
    (["scan", "smooth", "s.ply", "--out", "s.csv"], "--out s.csv: a mesh is written as .obj, "
     ".ply, .stl, .off or .glb, not .csv; name it s.obj"),
    (["scan", "fit", "s.ply", "--features", "f.json", "--out", "fit"], "--out fit: a mesh is "
     "written as .obj, .ply, .stl, .off or .glb, and the name has no extension; name it "
     "fit.obj"),
])
def test_an_output_named_for_another_format_is_refused_before_any_work(argv, says, tmp_path,
                                                                      monkeypatch, capsys):
    """A track named .mp4 (a zip archive a player refuses), a glb named .usd (a file USD
    cannot open), a page named .npz: refused by name, in one line, before any input is read
    (none of them exists here) and with nothing written."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = _err(capsys)
    assert len(err) == 1 and err[0].endswith(": error: " + says), err
    assert list(tmp_path.iterdir()) == []


def test_a_take_given_to_export_is_read_as_a_take(tmp_path, capsys):
    """A Live Link Face take where export wants a track is exported as the take on the model's
    mean person (test_take.py); one that holds no shape is said so in one line, before any
    model is loaded or built (before the fifty-first session: refused as "not a track"; before that,
    "truncated or not a track file" about a valid take)."""
    take = tmp_path / "take.csv"
    take.write_text("Timecode,BlendShapeCount\n")
    assert main(["export", str(take), "--out", str(tmp_path / "x.glb")]) == 2
    err = _err(capsys)
    assert len(err) == 1 and f"{take} lacks the columns ['EyeBlinkLeft'" in err[0], err
    assert not (tmp_path / "x.glb").exists()


def test_an_export_takes_its_format_from_the_outputs_extension(tmp_path):
    from facetransfer.export import ExportError, format_of

    assert [format_of(tmp_path / n) for n in ("t.csv", "f.GLB", "f.usda", "f.usdc", "b.json")] \
        == ["livelink", "glb", "usd", "usd", "json"]
    assert format_of("f.usdc", "usd") == "usd"
    with pytest.raises(ExportError, match="unknown export format 'fbx'"):
        format_of("f.fbx", "fbx")
    with pytest.raises(ValueError, match="a usd export is written as .usd, .usda or .usdc"):
        format_of("f.glb", "usd")


def test_a_transfers_saved_track_is_named_as_a_track(data_dir, tmp_path, capsys):
    clip = str(data_dir / "video" / "face_2.mp4")
    assert main(["transfer", "--target", clip, "--expression-from", clip, "--out",
                 str(tmp_path / "r.mp4"), "--save-track", str(tmp_path / "r.mov")]) == 2
    assert _err(capsys) == [f"facetransfer transfer: error: --save-track {tmp_path / 'r.mov'}: "
                            "a track is written as .npz, not .mov; name it r.npz"]
    assert list(tmp_path.iterdir()) == []


def test_meshes_naming_a_file_is_refused_before_any_work(data_dir, tmp_path, capsys):
    """``--meshes`` names a folder: a file there was found only after the whole render (a raw
    "File exists", and the video written); now refused first, nothing written."""
    clip = str(data_dir / "video" / "face_2.mp4")
    (tmp_path / "t1.mp4").write_bytes(b"x")
    assert main(["transfer", "--target", clip, "--expression-from", clip, "--out",
                 str(tmp_path / "r.mp4"), "--meshes", str(tmp_path / "t1.mp4")]) == 2
    assert _err(capsys) == [f"facetransfer transfer: error: --meshes {tmp_path / 't1.mp4'} is "
                            "a file; it names a folder for the meshes (frame_00000.obj, ...)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t1.mp4"]


def test_a_face_to_track_and_a_track_given_for_it_are_refused_together(data_dir, tmp_path,
                                                                       capsys):
    """``--target-face left`` with a ``--target-track`` (of the right person) rewrote the
    track's face and said nothing; the two contradict each other. A take with
    ``--source-face`` the same."""
    clip = str(data_dir / "video" / "face_2.mp4")
    assert main(["transfer", "--target", clip, "--target-track", str(tmp_path / "t.npz"),
                 "--target-face", "left", "--expression-from", clip,
                 "--out", str(tmp_path / "r.mp4")]) == 2
    assert _err(capsys) == [f"facetransfer transfer: error: --target-face chooses the face to "
                            f"track, but --target-track {tmp_path / 't.npz'} is tracked already "
                            "(its face is the one rewritten): give one of them"]
    take = tmp_path / "take.csv"
    take.write_text("Timecode,BlendShapeCount\n")
    assert main(["transfer", "--target", clip, "--expression-from", str(take), "--source-face",
                 "right", "--out", str(tmp_path / "r.mp4")]) == 2
    assert _err(capsys)[0].endswith("which drives the target alone: --source-face cannot be "
                                    "added")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.csv"]


@pytest.mark.parametrize("extra, says", [
    (["--gaze", "target", "--eyes", "target"], "--gaze target acts with --eyes model, not "
     "--eyes target: give one of them"),
    (["--lip-colour", "source", "--mouth", "function"], "--lip-colour source acts with "
     "--mouth frame, not --mouth function: give one of them"),
])
def test_an_option_that_would_be_ignored_is_refused(extra, says, data_dir, tmp_path, capsys):
    """An option that acts only with another's value, given with another (it was ignored in
    silence): one line, nothing written."""
    clip = str(data_dir / "video" / "face_2.mp4")
    assert main(["transfer", "--target", clip, "--expression-from", clip,
                 "--out", str(tmp_path / "r.mp4"), *extra]) == 2
    assert _err(capsys) == [f"facetransfer transfer: error: {says}"]
    assert list(tmp_path.iterdir()) == []


def test_a_track_run_stopped_before_its_overlay_is_pointed_to_from_track(data_dir, tmp_path,
                                                                          capsys):
    """``track --out T --overlay O`` stopped after writing T: the same command again said only
    "T exists; pass --overwrite" (tracking again); it now says how to draw just the overlay
    (test_walk47); a file there that is no track is only said to exist (``--from-track``
    would not read it)."""
    clip = str(data_dir / "video" / "face_2.mp4")
    t, o = tmp_path / "t.npz", tmp_path / "o.mp4"
    t.write_bytes(b"an earlier run's track")
    assert main(["track", clip, "--out", str(t), "--overlay", str(o)]) == 2
    err = _err(capsys)
    assert len(err) == 1 and err[0].startswith(f"facetransfer track: error: output {t} "
                                               "exists") and "--from-track" not in err[0], err
    assert t.read_bytes() == b"an earlier run's track" and not o.exists()


# ------------------------------------------------------------------------------ native logs
def test_native_log_lines_are_filtered_from_stderr():
    """C libraries write straight to descriptor 2, often in pieces; only they are dropped."""
    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {SRC!r})
        from facetransfer.cli.stderr import filtered_stderr
        with filtered_stderr():
            os.write(2, b"W0000 00:00:1796140392.727433    7411 feedback.cc:121] Feedback\\n")
            os.write(2, b"INFO: ")
            os.write(2, b"Created TensorFlow Lite XNNPACK delegate for CPU.")
            os.write(2, b"\\n")
            # the forked tracker's lines interleaved with this process's
            os.write(2, b"INFO: ")
            os.write(2, b"W0000 00:00:1796153087.416123   21600 feedback.cc:121] Feedback\\n")
            os.write(2, b"Created TensorFlow Lite XNNPACK delegate for CPU.\\n")
            os.write(2, b"WARNING: ")
            os.write(2, b"W0000 00:00:1796153087.5   21601 graph.cc:181] Sets xnnpack\\n")
            os.write(2, b"Logging before InitGoogle() is written to STDERR\\n")
            os.write(2, b"INFO: INFO: Created TensorFlow Lite XNNPACK delegate for CPU.\\n")
            print("\\rbar 50%", end="", file=sys.stderr, flush=True)
            print("facetransfer x: error: the tool's own line", file=sys.stderr)
            os.write(2, b"F0000 00:00:1.0  1 fatal.cc:1] a fatal native error\\n")
            os.write(2, b"\\n")  # a blank line stays (written after the prints: the pump is late)
        print("after", file=sys.stderr)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
    err = r.stderr.decode()
    assert r.returncode == 0
    assert "Feedback" not in err and "TensorFlow" not in err and "INFO" not in err
    assert "xnnpack" not in err and "WARNING" not in err and "InitGoogle" not in err
    assert "\rbar 50%facetransfer x: error: the tool's own line\n" in err
    assert err.count("\n\n") == 1  # the blank line (through the filter, so maybe later)
    assert "a fatal native error" in err and err.endswith("after\n")


def test_the_filters_end_does_not_wait_for_a_child_holding_the_pipe():
    """A process that inherited the filtered descriptor 2 (a Dask worker shutting down) keeps
    the pump reading: the block's end waits DRAIN_SECONDS, not until the child exits (it waited
    2 s after every batch run, and a Ctrl-C then printed a traceback), and leaves descriptor 2's
    copy open while the pump may still write to it; closes it once the pump has ended."""
    import os
    import threading

    from facetransfer.cli import stderr as fs

    assert fs.DRAIN_SECONDS <= 0.5
    go = threading.Event()
    pump = threading.Thread(target=go.wait, daemon=True)
    pump.start()
    fd = os.dup(2)
    fs._drained(pump, fd)
    os.fstat(fd)                                  # still open: the pump may write to it
    go.set()
    pump.join()
    fs._drained(pump, fd)
    with pytest.raises(OSError):
        os.fstat(fd)                              # closed once the pump has ended


# ------------------------------------------------------------------------------ native threads
def test_serial_blas_only_for_the_commands_that_run_their_own_parallel_work():
    from facetransfer.cli.main import SERIAL_BLAS_COMMANDS, serial_blas

    for argv in (["transfer", "--target", "t.mp4"], ["-v", "track", "v.mp4"], ["demo"]):
        env = {}
        assert serial_blas(argv, env)
        assert env == {"OPENBLAS_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}
    env = {"OPENBLAS_NUM_THREADS": "2", "OPENCV_FOR_THREADS_NUM": "3"}  # the user's choice is kept
    assert serial_blas(["puppet", "x"], env)
    assert env == {"OPENBLAS_NUM_THREADS": "2", "OPENCV_FOR_THREADS_NUM": "3"}
    for argv in (["model", "build", "ict-arkit"], ["--help"], []):
        env = {}
        assert not serial_blas(argv, env) and env == {}
    assert {"track", "transfer", "puppet", "demo", "edit"} == SERIAL_BLAS_COMMANDS


def test_console_script_sets_serial_blas_before_numpy_loads_openblas():
    """main() without argv (the console script) sets the variables before anything imports
    NumPy, whose OpenBLAS reads its once, when it loads (and OpenCV its own, when imported)."""
    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {SRC!r})
        os.environ.pop("OPENBLAS_NUM_THREADS", None)
        sys.argv = ["facetransfer", "transfer", "--help"]
        from facetransfer.cli.main import main
        assert "numpy" not in sys.modules
        try:
            main()
        except SystemExit:
            pass
        import cv2
        print(os.environ.get("OPENBLAS_NUM_THREADS"), "numpy" in sys.modules,
              cv2.getNumThreads())
    """)
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FOR_THREADS_NUM"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-3:] == ["1", "True", "1"]  # OpenCV's pool: one thread


# ------------------------------------------------------------------------------ --no-progress
class _Terminal:
    """A stderr that says it is a terminal and keeps what is written to it."""

    def __init__(self) -> None:
        self.text = ""

    def isatty(self) -> bool:
        return True

    def write(self, s: str) -> int:
        self.text += s
        return len(s)

    def flush(self) -> None:
        pass


def test_every_command_takes_no_progress_and_it_silences_the_bars(monkeypatch):
    """Every command and subcommand accepts ``--no-progress``; a bar then draws nothing even on
    a terminal, where without it it draws."""
    from facetransfer.cli import common
    from facetransfer.cli.main import _leaf_parsers, build_parser

    parser = build_parser()
    leaves = list(_leaf_parsers(parser))
    assert len(leaves) >= 15
    assert all("--no-progress" in p._option_string_actions for p in leaves)
    assert parser.parse_args(["track", "v.mp4", "--no-progress"]).no_progress
    assert not parser.parse_args(["model", "info", "m.npz"]).no_progress
    try:
        for enabled in (True, False):
            term = _Terminal()
            monkeypatch.setattr(sys, "stderr", term)
            common.set_progress(enabled)
            assert common.progress_shown() is enabled
            cb, close = common.tqdm_progress("frames")
            cb(3, 10)
            close()
            assert ("frames" in term.text) is enabled
    finally:
        common.set_progress(True)


def test_every_bar_is_drawn_on_a_terminal_only():
    """tqdm draws into a pipe or a log file unless told otherwise (``batch``'s bar filled the
    log of ``facetransfer batch track ... 2>log``): every bar the package makes passes
    ``disable=`` (:func:`facetransfer.cli.common.progress_disabled`: a terminal only, and
    not after ``--no-progress``; None, tqdm's own rule, for a download)."""
    import ast

    import facetransfer

    root = Path(facetransfer.__file__).parent
    bars, missing = 0, []
    for f in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Call) and \
                    getattr(node.func, "id", getattr(node.func, "attr", None)) == "tqdm":
                bars += 1
                if not any(k.arg == "disable" for k in node.keywords):
                    missing.append(f"{f.relative_to(root)}:{node.lineno}")
    assert bars >= 10 and missing == []


# ------------------------------------------------------------------------------ a closed pipe
def test_output_read_by_a_reader_that_stops_ends_quietly(data_dir):
    """``facetransfer probe V | head -1``: the command's output goes to a pipe whose reader
    has gone (here closed before it starts, so that nothing depends on timing); it ends with
    no error line (before: "error: Broken pipe", status 2, or Python's "Exception ignored"
    at exit) and a shell's status for SIGPIPE; a real error still says its line."""
    clip = str(data_dir / "video" / "driving_d9.mp4")
    env = {**os.environ, "PYTHONPATH": SRC}
    for n in (1, 40):                 # flushed at the end; flushed while running
        r, w = os.pipe()
        os.close(r)
        try:
            res = subprocess.run([sys.executable, "-m", "facetransfer.cli.main", "probe",
                                  *[clip] * n], stdout=w, stderr=subprocess.PIPE, text=True,
                                 timeout=120, env=env)
        finally:
            os.close(w)
        assert res.returncode == 141 and res.stderr == "", (n, res.stderr)
    res = subprocess.run([sys.executable, "-m", "facetransfer.cli.main", "probe", clip + ".no"],
                         capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 2 and "does not exist" in res.stderr


def test_the_paper_tracker_answers_to_both_its_names():
    """``track`` called the optical-flow tracker ``klt``, ``transfer`` and ``puppet`` called
    it ``flow``: each command takes both (a newcomer's reading of the code)."""
    from facetransfer.cli.main import build_parser

    p = build_parser()
    assert p.parse_args(["track", "v.mp4", "--out", "t.npz", "--tracker", "flow"]).tracker == \
        "klt"
    assert p.parse_args(["track", "v.mp4", "--out", "t.npz", "--tracker", "klt"]).tracker == \
        "klt"
    for argv in (["transfer", "--target", "t.mp4", "--expression-from", "s.mp4", "--out",
                  "o.mp4"], ["puppet", "v.mp4", "--out", "o.mp4"]):
        assert p.parse_args(argv + ["--tracker", "klt"]).tracker == "flow"
        assert p.parse_args(argv + ["--tracker", "flow"]).tracker == "flow"


def test_a_commands_sequence_rate_ends_with_it(monkeypatch, capsys):
    """``--sequence-fps`` reaches a command's readers and children through the environment;
    a command run in this process (``main(argv)``) leaves it as it was, so that the next
    command reads image sequences at its own rate (before, at the previous command's)."""
    from facetransfer.cli.main import main
    from facetransfer.io.video_sequence import SEQUENCE_FPS_VARIABLE

    monkeypatch.delenv(SEQUENCE_FPS_VARIABLE, raising=False)
    assert main(["probe", "/nonexistent/plate.%04d.png", "--sequence-fps", "25"]) == 2
    assert SEQUENCE_FPS_VARIABLE not in os.environ
    monkeypatch.setenv(SEQUENCE_FPS_VARIABLE, "30.0")
    assert main(["probe", "/nonexistent/plate.%04d.png", "--sequence-fps", "25"]) == 2
    assert os.environ[SEQUENCE_FPS_VARIABLE] == "30.0"
    capsys.readouterr()


def test_a_ctrl_c_while_the_commands_load_is_one_line_and_130(monkeypatch, capsys):
    """A Ctrl-C in the first half second (the subcommands' modules importing, before the
    command's own handling began) printed the import's traceback and died of the signal."""
    from facetransfer.cli import main as cli_main

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main, "build_parser", interrupted)
    assert main(["track", "x.mp4", "--out", "t.npz"]) == 130
    assert _err(capsys) == ["facetransfer: interrupted"]


def test_a_sigterm_while_the_commands_load_is_one_line_and_143():
    """A SIGTERM in the first half second (the subcommands' modules importing: before the
    command's own handler was set, 0.05-0.35 s into a transfer on a loaded machine) killed the
    process by the signal, with no line; now as a Ctrl-C then: one line and 143. In a process
    of its own: before, the signal ended it."""
    code = textwrap.dedent("""
        import os, signal, sys
        from facetransfer.cli import main as cli_main

        def loading():
            os.kill(os.getpid(), signal.SIGTERM)
            raise SystemExit("the SIGTERM was not taken")

        cli_main.build_parser = loading
        sys.exit(cli_main.main(["track", "x.mp4", "--out", "t.npz"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": SRC})
    assert (r.returncode, r.stderr.splitlines()) == (143, ["facetransfer: terminated"])


#: :func:`_ignored_interrupt`'s timer whose signal comes before its ``start()`` returns (a
#: loaded machine: the re-sent signal 10 ms later, the main thread still waiting in the hook for
#: the timer's thread to start), once.
EARLY_TIMER = """
    import threading
    from facetransfer import signals

    class Early(threading.Timer):
        fired = False

        def start(self):
            if Early.fired:
                return super().start()
            Early.fired = True
            os.kill(os.getpid(), self.args[0])

    signals.threading.Timer = Early
"""


def _ignored_interrupt(signum: str, early: bool) -> subprocess.CompletedProcess:
    """A command whose handler of ``signum`` runs inside a weak reference's callback (where
    Python ignores exceptions); ``early``: the signal it is sent again comes while the hook that
    sends it still runs (:data:`EARLY_TIMER`)."""
    code = textwrap.dedent(f"""
        import os, signal, sys, time, weakref
        from facetransfer.cli import main as cli_main

        class Thing:
            pass

        def loading():
            thing = Thing()
            ref = weakref.ref(thing, lambda r: (os.kill(os.getpid(), signal.{signum}),
                                                sum(range(1000))))
            del thing                                   # the handler runs in the callback
            time.sleep(30)                              # the command goes on
            raise SystemExit("the signal was lost")

        cli_main.build_parser = loading
    """) + (textwrap.dedent(EARLY_TIMER) if early else "") + \
        'sys.exit(cli_main.main(["track", "x.mp4", "--out", "t.npz"]))\n'
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "PYTHONPATH": SRC})


@pytest.mark.parametrize("signum,said", [("SIGTERM", (143, "terminated")),
                                          ("SIGINT", (130, "interrupted"))])
def test_an_interrupt_inside_a_callback_python_ignores_is_taken(signum, said):
    """A SIGTERM or Ctrl-C whose handler ran inside a callback where Python ignores exceptions
    (a weak reference's, as importlib's module locks have: 1 of 21 SIGTERMs 0.8 s into a
    transfer) printed "Exception ignored ... Terminated" and was lost: the transfer ran to its
    end, exit 0. It is now given again a moment later, and taken in the code running then."""
    r = _ignored_interrupt(signum, early=False)
    assert (r.returncode, r.stderr.splitlines()) == (said[0], [f"facetransfer: {said[1]}"])


@pytest.mark.parametrize("signum,said", [("SIGTERM", (143, "terminated")),
                                          ("SIGINT", (130, "interrupted"))])
def test_an_interrupt_given_again_while_its_hook_still_runs_is_taken(signum, said):
    """The signal sent again came while the hook sending it still waited for the timer's thread
    to start (the clean-clone CI, make test beside it: "Exception ignored in
    sys.unraisablehook ... Terminated", the signal lost, exit 1): a handler raises nothing while
    the hook runs; it sends its signal again, taken once the hook has returned."""
    r = _ignored_interrupt(signum, early=True)
    assert (r.returncode, r.stderr.splitlines()) == (said[0], [f"facetransfer: {said[1]}"])


def _raised_after_it(setup: str, handler: str, signum: str, frame: str) -> None:
    """Run ``setup`` (Python code making ``frame``, an expression of a frame where the CLI's
    ``handler`` must not raise), call the handler there as ``signum`` would, and check that
    it raised nothing there and that the signal, sent again, was raised after it."""
    code = setup + textwrap.dedent(f"""
        signal.signal(signal.{signum}, cli_main.{handler})
        try:
            cli_main.{handler}(signal.{signum}, {frame})
        except KeyboardInterrupt:
            sys.exit("raised inside the frame")
        try:
            time.sleep(30)
        except KeyboardInterrupt:
            sys.exit(0)
        sys.exit("not sent again")
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": SRC})
    assert (r.returncode, r.stderr) == (0, "")


@pytest.mark.parametrize("handler,signum,where", [
    ("_terminated", "SIGTERM", "cb"), ("_interrupted", "SIGINT", "cb")])
def test_an_interrupt_inside_importlibs_lock_callback_is_raised_after_it(handler, signum,
                                                                         where):
    """importlib's module-lock callback (``cb``, run when a module's lock is collected: no
    trace function catches it on demand, so its frame is made here) takes the global import
    lock before its ``try``: an interrupt raised there right after it took the lock left the
    lock held for ever, and the transfer's other threads hung at their next import (a Ctrl-C
    2 s in, killed 120 s later). The CLI's handlers raise nothing in importlib's code; the
    signal is sent again and raised after it (``_get_module_lock``, ``acquire``: the next
    test, on real frames)."""
    code = textwrap.dedent(f"""
        import signal, sys, time
        from facetransfer.cli import main as cli_main

        ns = {{"__name__": "importlib._bootstrap", "sys": sys}}
        exec("def {where}():\\n    return sys._getframe()\\n", ns)     # importlib's frame
    """)
    _raised_after_it(code, handler, signum, f'ns["{where}"]()')


@pytest.mark.parametrize("handler,signum,where", [
    ("_interrupted", "SIGINT", "_get_module_lock"), ("_interrupted", "SIGINT", "acquire"),
    ("_terminated", "SIGTERM", "_get_module_lock"), ("_interrupted", "SIGINT", "handle")])
def test_an_interrupt_inside_importlibs_or_loggings_lock_taking_is_raised_after_it(
        handler, signum, where):
    """importlib's ``_get_module_lock`` takes the global import lock before its ``try``,
    ``_ModuleLock.acquire`` a module's lock before it returns, logging's ``Handler.handle``
    its lock before its ``try``: a Ctrl-C raised there left the lock held for ever, and the
    transfer's main thread, interrupted as it imported, waited for ever for its MediaPipe and
    kernel loading threads, stuck at their next import (a lone SIGINT 1.3-2.7 s in: 3 of 45
    runs hung, nothing said). The handlers raise nothing in such a frame (real ones, caught
    by a trace function); the signal is sent again and raised after it."""
    code = textwrap.dedent(f"""
        import logging, signal, sys, time
        from facetransfer.cli import main as cli_main

        seen = []

        def tracer(frame, event, arg):
            if frame.f_code.co_name == {where!r} and not seen:
                seen.append(frame)

        sys.modules.pop("json", None)
        sys.settrace(tracer)
        import json                                  # a module's lock taken
        logging.getLogger("t").addHandler(logging.NullHandler())
        logging.getLogger("t").error("x")            # a handler's lock taken
        sys.settrace(None)
        assert seen[0].f_globals["__name__"] in ("importlib._bootstrap", "logging"), seen
    """)
    _raised_after_it(code, handler, signum, "seen[0]")


def test_an_interrupted_run_names_an_earlier_output_it_replaced(tmp_path, capsys):
    """``track --out T.npz --overlay O.mp4 --overwrite`` interrupted while drawing the overlay
    had already replaced the earlier T.npz, but its line said only "interrupted": an output is
    named as written when it is another file than before (it named only new ones)."""
    import argparse

    from facetransfer.cli import main as cli_main

    out = tmp_path / "t.npz"
    out.write_bytes(b"an earlier run's track")

    def replace_then_stop(args):
        tmp = tmp_path / ".t.part.npz"
        tmp.write_bytes(b"this run's track")
        os.replace(tmp, out)
        raise KeyboardInterrupt                   # in the overlay

    args = argparse.Namespace(command="track", out=str(out), verbose=False,
                              func=replace_then_stop)
    assert cli_main._run(args) == 130
    assert _err(capsys) == [f"facetransfer track: interrupted; it had written {out}: run it "
                            "again with --overwrite to replace them"]
    untouched = argparse.Namespace(command="track", out=str(out), verbose=False,
                                   func=lambda args: (_ for _ in ()).throw(KeyboardInterrupt))
    assert cli_main._run(untouched) == 130
    assert _err(capsys) == ["facetransfer track: interrupted"]


def test_commands_run_in_threads_leave_the_process_unraisable_hook_as_it_was(monkeypatch):
    """A program running commands in threads (:func:`main` with ``argv``): each command set the
    process's :func:`sys.unraisablehook` (:func:`facetransfer.signals.interrupts_not_ignored`)
    and put back the one it found; two commands at once put them back out of order, and the
    first one's hook stayed for ever (re-sending the program's own ignored interrupts). Only
    the main thread, the one whose signal handlers the CLI sets, sets it."""
    import threading

    from facetransfer.cli import main as cli_main

    a_in, b_in = threading.Event(), threading.Event()

    def command(argv, process_ends=False):
        if argv == ["a"]:
            a_in.set()
            assert b_in.wait(10)          # b sets its hook while a's is set
        else:
            b_in.set()
            a.join(10)                    # a has put back the hook it found
        return 0

    monkeypatch.setattr(cli_main, "_main", command)
    before = sys.unraisablehook
    a = threading.Thread(target=main, args=(["a"],))
    b = threading.Thread(target=main, args=(["b"],))
    a.start()
    assert a_in.wait(10)
    b.start()
    b.join(10)
    a.join(10)
    assert sys.unraisablehook is before


def test_a_callers_own_sigterm_handler_is_kept_while_a_command_runs(monkeypatch):
    """A program with its own SIGTERM handler (a server's orderly shutdown) that runs a command
    in process (:func:`main` with ``argv``): the command replaced it with its own for its
    length, so a SIGTERM then stopped the command (143) and the program never heard of it. A
    caller's handler is kept, as a caller's Ctrl-C handler already was."""
    import signal
    import time

    from facetransfer.cli import main as cli_main

    heard = []

    def command(argv, process_ends=False):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.5)                        # the handler runs here
        return 0

    monkeypatch.setattr(cli_main, "_main", command)
    before = signal.signal(signal.SIGTERM, lambda signum, frame: heard.append(signum))
    try:
        assert main(["probe", "x.mp4"]) == 0
    finally:
        signal.signal(signal.SIGTERM, before)
    assert heard == [signal.SIGTERM]


# ---------------------------------------------------------------------- python -m facetransfer
def test_python_dash_m_facetransfer_runs_the_command_line(tmp_path):
    """``python -m facetransfer …`` is the console script (it said "No module named
    facetransfer.__main__", status 1): its version, a usage error in one line naming the
    command with status 2, and a command's work."""
    import facetransfer

    env = {**os.environ, "PYTHONPATH": SRC}

    def run(*args):
        return subprocess.run([sys.executable, "-m", "facetransfer", *args], capture_output=True,
                              text=True, timeout=120, env=env, cwd=tmp_path)

    r = run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"facetransfer {facetransfer.__version__}"
    r = run("render", "--nope")
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [
        "facetransfer render: error: unrecognized arguments: --nope "
        "(options: facetransfer render --help)"]
    r = run("probe", "missing.mp4")
    assert r.returncode == 2 and "missing.mp4" in r.stderr and "Traceback" not in r.stderr


def test_no_help_states_an_empty_or_missing_default():
    """Every command's ``--help``: no option says "(default: [])" (``edit --add`` and
    ``--scale``, repeatable options given none, did), "(default: None)" or "(default: ())"."""
    import argparse
    import re

    from facetransfer.cli.main import build_parser

    def parsers(parser, path):
        yield path, parser
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from parsers(sub, f"{path} {name}")

    found = [(path, m) for path, parser in parsers(build_parser(), "facetransfer")
             for m in re.findall(r"\(default: (\[\]|None|\(\)|'')\)", parser.format_help())]
    assert found == []
    helps = dict(parsers(build_parser(), "facetransfer"))
    assert "--add EXPR@START-END" in helps["facetransfer edit"].format_help()
    # an option with a default says it ("default" the word: --speed's help named "the flow
    # tracker's defaults" and never its own, fast)
    silent = [(path, a.option_strings[-1]) for path, parser in helps.items()
              for a in parser._actions if a.option_strings and a.help
              and a.default not in (None, False, [], argparse.SUPPRESS)
              and not re.search(r"\bdefault\b", parser._get_formatter()._get_help_string(a),
                                re.I)]
    assert silent == []
    speed = helps["facetransfer transfer"].format_help().split("--speed")[-1]
    assert "(default: fast)" in " ".join(speed.split())


@pytest.mark.parametrize("argv, ext", [
    (["edit", "t.npz", "--scale", "jawOpen=2", "--out", "FOLDER"], ".npz"),
    (["edit", "t.npz", "--add", "blink@1-2", "--out", "FOLDER/"], ".npz"),
    (["view", "t.npz", "--out", "FOLDER"], ".html"),
    (["track", "clip.mp4", "--out", "FOLDER"], ".npz"),
])
def test_an_existing_folder_as_the_output_is_said_to_be_one(argv, ext, tmp_path, monkeypatch,
                                                            capsys):
    """``edit T.npz --out out/`` said "a track is written as .npz, and the name has no
    extension; name it out.npz": a file beside the folder the user meant to write into. Now the
    line says the output is a folder and names a file in it, before any input is read."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "FOLDER").mkdir()
    assert main(argv) == 2
    err = _err(capsys)
    assert err == [f"facetransfer {argv[0]}: error: --out FOLDER is a folder; give a file name "
                   f"in it (FOLDER/NAME{ext})"], err
    assert [p.name for p in tmp_path.iterdir()] == ["FOLDER"]
    assert list((tmp_path / "FOLDER").iterdir()) == []
