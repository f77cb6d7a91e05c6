"""Broken and odd inputs other than track files: Live Link Face takes, meshes, MediaPipe
landmark files, model files, videos. Each is read right or refused with one error naming the
file (exit status 2, one line, at the commands), never another exception, a hang or a quietly
wrong result. Each case was found by fuzzing (the forty-fifth session); its "before" is in its
docstring.
"""

from __future__ import annotations

import logging
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facetransfer.errors import MeshError, VideoError
from facetransfer.transfer import TransferError

FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def _cli(argv, capsys) -> tuple[int, list[str]]:
    from facetransfer.cli.main import main

    status = main([str(a) for a in argv])
    return status, [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


# ------------------------------------------------------------------------------ takes
def _take_text(timecodes) -> str:
    from facetransfer.export.livelink import LIVELINK_NAMES, POSE_COLUMNS

    head = ["Timecode", "BlendShapeCount", *LIVELINK_NAMES, *POSE_COLUMNS]
    cells = ",".join(["0.25"] * (len(head) - 2))
    return "\n".join([",".join(head)] + [f"{tc},61,{cells}" for tc in timecodes]) + "\n"


@pytest.mark.parametrize("timecodes,says", [
    (["01:00:00:05.000"] * 10, "repeat at row 2"),
    (["00:00:00:00.000", "23:00:00:00.000"], "leap 82800 s at row 2"),
    (["01:00:00:10.000", "01:00:00:11.000", "01:00:00:11.000"], "repeat at row 3"),
])
def test_take_timecodes_that_repeat_or_leap_are_refused(timecodes, says):
    """Before: ten rows of one timecode made a take of one frame (said nowhere); rows 23 hours
    apart made ``view take.csv`` fill two million frames (a hang)."""
    from facetransfer.take import take_seconds

    with pytest.raises(TransferError, match=says) as e:
        take_seconds(timecodes, name="take t.csv")
    assert "take t.csv's timecodes" in str(e.value)


def test_a_takes_impossible_frame_number_names_the_take():
    """Before: "timecode frame 504 is beyond every timecode rate", naming no file."""
    from facetransfer.take import take_seconds

    with pytest.raises(TransferError, match="frame 504 of take t.csv is beyond"):
        take_seconds(["01:00:00:504.000"], name="take t.csv")


@FUZZ
@given(rows=st.lists(st.tuples(st.integers(0, 23), st.integers(0, 59), st.integers(0, 59),
                               st.integers(0, 29), st.integers(0, 999)), min_size=1,
                     max_size=8))
def test_take_seconds_rise_by_at_most_a_minute_or_are_refused(rows):
    """Property: any timecodes give seconds that rise, a row at most a minute after the one
    before (a day added past midnight), or one TransferError; never another exception."""
    from facetransfer.take import MAX_ROW_GAP, take_seconds

    tcs = [f"{h:02d}:{m:02d}:{s:02d}:{f:02d}.{k:03d}" for h, m, s, f, k in rows]
    try:
        t = take_seconds(tcs, warn=False)
    except TransferError:
        return
    step = np.diff(t)
    assert t[0] == 0 and np.all(step > 0) and np.all(step <= MAX_ROW_GAP)


def test_probe_of_a_take_with_a_leap_is_one_line_naming_it(tmp_path, capsys):
    """``probe`` reads a take's timecodes too: one line naming it, no log line before it
    (before: the rate's guess was said first, then the error)."""
    p = tmp_path / "gap.csv"
    p.write_text(_take_text(["00:00:00:00.000", "23:00:00:00.000"]))
    status, err = _cli(["probe", p], capsys)
    assert status == 2 and len(err) == 1 and "gap.csv" in err[0] and "leap" in err[0], err


def test_a_take_of_repeated_timecodes_says_no_guess_before_its_error(caplog):
    """Within one second the take's rate is a guess, said in the log; a take refused for its
    timecodes says only why (before: the guess, then the error)."""
    from facetransfer.take import take_seconds

    with caplog.at_level(logging.WARNING, logger="facetransfer.take"), \
            pytest.raises(TransferError, match="repeat"):
        take_seconds(["01:00:00:05.000"] * 3, name="take t.csv")
    assert not caplog.records


# ------------------------------------------------------------------------------ meshes
def test_obj_vertices_of_two_numbers_are_refused_by_both_readers(tmp_path):
    """Before: :func:`read_obj_vertices` read the six numbers of three 2-number lines as two
    vertices."""
    from facetransfer.io.mesh import read_mesh, read_obj_vertices

    p = tmp_path / "flat.obj"
    p.write_text("v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n")
    for read in (read_obj_vertices, read_mesh):
        with pytest.raises(MeshError, match="flat.obj has malformed vertex lines"):
            read(p)


def test_an_obj_with_a_byte_order_mark_keeps_its_first_vertex(tmp_path):
    """Before: the mark hid the first ``v`` line: ``read_mesh`` refused the faces (indices
    out of range), ``read_obj_vertices`` returned one vertex fewer."""
    from facetransfer.io.mesh import read_mesh, read_obj_vertices

    p = tmp_path / "bom.obj"
    p.write_bytes(b"\xef\xbb\xbfv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n")
    expected = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    assert read_obj_vertices(p).tolist() == expected
    m = read_mesh(p)
    assert m.vertices.tolist() == expected and m.faces.tolist() == [[0, 1, 2]]


def test_an_obj_face_index_beyond_int64_is_one_error(tmp_path):
    """Before: OverflowError ("Python int too large to convert to C long")."""
    from facetransfer.io.mesh import read_mesh

    p = tmp_path / "huge.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n")
    with pytest.raises(MeshError, match="huge.obj has a face index 9+ outside"):
        read_mesh(p)


_PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex {v}\nproperty float x\nproperty float y\n"
             "property float z\nelement face {f}\nproperty list uchar int vertex_indices\n"
             "end_header\n")


def test_an_ascii_ply_cut_short_is_refused(tmp_path):
    """Before: read as the two vertices before the cut and no faces, said nowhere."""
    from facetransfer.io.mesh import read_mesh

    p = tmp_path / "cut.ply"
    p.write_text(_PLY_HEAD.format(v=5, f=1) + "0 0 0\n1 0 0\n")
    with pytest.raises(MeshError, match="cut.ply is truncated: its header declares 5 vertices"):
        read_mesh(p)


def test_a_whole_ply_of_quads_still_reads(tmp_path):
    """The count check lets a complete file through: a quad is two triangles (more faces read
    than declared), vertex order kept."""
    from facetransfer.io.mesh import read_mesh

    p = tmp_path / "quads.ply"
    p.write_text(_PLY_HEAD.format(v=4, f=2) + "0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n4 0 1 3 2\n")
    m = read_mesh(p)
    assert m.vertices.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
    assert len(m.faces) == 3 and m.faces.max() == 3


#: OBJ lines and the vertex each gives: None, none (not a vertex line); "bad", the file is
#: refused.
_OBJ_LINES = [("v 0 0 0", [0, 0, 0]), ("v 1 2 3", [1, 2, 3]), ("v 1 2 3 4", [1, 2, 3]),
              ("v  1  2  3", [1, 2, 3]), ("v 4 5 6\r", [4, 5, 6]), ("vt 0 0", None),
              ("# c", None), ("", None), ("v 1 2", "bad"), ("v a b c", "bad"),
              ("v nan 0 0", "bad"), ("v 1e400 0 0", "bad")]


@FUZZ
@given(picks=st.lists(st.sampled_from(range(len(_OBJ_LINES))), min_size=1, max_size=8),
       bom=st.booleans())
def test_both_obj_readers_read_exactly_the_vertex_lines(tmp_path, picks, bom):
    """Property: :func:`read_obj_vertices` (the fast reader of a data set's meshes) and
    :func:`read_obj` give exactly the file's vertex lines, in order, or refuse a file with a
    bad one (or none). It found the byte-order mark that hid the first vertex."""
    from facetransfer.io.mesh import read_obj, read_obj_vertices

    lines = [_OBJ_LINES[k] for k in picks]
    p = tmp_path / "m.obj"
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + "\n".join(t for t, _ in lines).encode())
    want = [v for _, v in lines if v is not None]
    for read in (read_obj_vertices, lambda q: read_obj(q).vertices):
        if "bad" in want or not want:
            with pytest.raises(MeshError, match="m.obj"):
                read(p)
        else:
            assert read(p).tolist() == want, lines


# ------------------------------------------------------------------------------ landmarks
def test_landmarks_of_absurd_size_are_refused(tmp_path):
    """Before: 1e300 passed the reader and overflowed the landmark fit (OverflowError, a
    traceback from ``transfer --tracker landmarks``)."""
    from facetransfer.io.landmarks import read_mediapipe_landmarks

    p = tmp_path / "clip.mediapipe478.npz"
    np.savez(p, landmarks=np.full((3, 478, 3), 1e300))
    with pytest.raises(VideoError, match="clip.mediapipe478.npz has coordinates beyond"):
        read_mediapipe_landmarks(p)


def test_landmarks_off_the_frames_or_short_are_said(tmp_path, caplog):
    """Landmarks of another clip (off the 320x240 frames) are refused naming the file; fewer
    frames than the clip's are said. Before: both fitted, said nowhere."""
    from facetransfer.track.obtain import _check_landmarks_fit

    P = np.zeros((3, 478, 3))
    P[..., 0], P[..., 1] = 160.0, 120.0
    p = Path("clip.mediapipe478.npz")
    _check_landmarks_fit(p, P, 3, (320, 240))          # in frame, every frame: nothing said
    P[1, :, 0] = -400.0
    with pytest.raises(VideoError, match="points off the video's 320x240 frames"):
        _check_landmarks_fit(p, P, 3, (320, 240))
    P[1, :, 0] = np.nan                               # no face on frame 1: fine
    with caplog.at_level(logging.WARNING):
        _check_landmarks_fit(p, P, 5, (320, 240))
    assert "has 3 frames of the 5 read" in caplog.text


# ------------------------------------------------------------------------------ models
def test_a_track_given_as_the_model_is_named_as_a_track(tmp_path, capsys):
    """Before: "... is not a facetransfer model file (no metadata)"."""
    from facetransfer.track.result import Track

    F = 2
    t = Track(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (F, 1, 1)),
              scale=np.ones(F), translation=np.zeros((F, 2)),
              weights={"identity": np.ones((F, 2)), "expression": np.zeros((F, 3))},
              landmarks2d=np.zeros((F, 68, 2)), confidence=np.ones(F), lost=np.zeros(F, bool),
              model_hash="abc", mode_names=("identity", "expression"))
    p = t.save(tmp_path / "t.npz")
    status, err = _cli(["model", "info", p], capsys)
    assert status == 2 and len(err) == 1 and "t.npz" in err[0] and "it is a track file" in \
        err[0], err


# ------------------------------------------------------------------------------ videos
def _ffmpeg(*args: str) -> None:
    import imageio_ffmpeg

    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", *args],
                   check=True)


def _info_error(path: Path) -> str:
    from facetransfer.io.video_read import video_info

    with pytest.raises(VideoError) as e:
        video_info(path)
    assert path.name in str(e.value)
    return str(e.value)


def test_a_video_cut_in_half_is_said_to_be_cut_short(tmp_path, data_dir):
    """The first half of a real clip (its index, ``moov``, at the end). Before: "not a video
    OpenCV can decode"."""
    raw = (data_dir / "video" / "face_2.mp4").read_bytes()
    p = tmp_path / "half.mp4"
    p.write_bytes(raw[:len(raw) // 2])
    assert "cut short" in _info_error(p)


def test_sound_alone_is_said_to_have_no_video_stream(tmp_path):
    """Before: "not a video OpenCV can decode"."""
    p = tmp_path / "sound.mp4"
    _ffmpeg("-f", "lavfi", "-i", "sine=frequency=440:duration=0.5", "-c:a", "aac", str(p))
    assert "sound and no video stream" in _info_error(p)


def test_a_recording_of_no_frames_is_said_to_hold_no_stream(tmp_path):
    """An MP4 written with no frame (a recording stopped at once). Before: "not a video OpenCV
    can decode"."""
    p = tmp_path / "none.mp4"
    _ffmpeg("-f", "lavfi", "-i", "color=c=gray:s=64x48:r=25", "-frames:v", "0", "-c:v",
            "libx264", str(p))
    assert "no stream at all" in _info_error(p)


def test_a_text_file_named_mp4_is_said_to_be_text(tmp_path):
    p = tmp_path / "notes.mp4"
    p.write_text("not a video\n" * 10)
    assert "text file" in _info_error(p)


def _moov_end(data: bytes) -> int:
    """The offset just past the top-level ``moov`` box of an MP4."""
    at = 0
    while at + 8 <= len(data):
        size, kind = int.from_bytes(data[at:at + 4], "big"), data[at + 4:at + 8]
        if kind == b"moov":
            return at + size
        at += size
    raise AssertionError("no moov box")


@pytest.mark.parametrize("name, data, said", [
    ("face.glb", b"glTF\x02\x00\x00\x00" + bytes(64), "a glTF binary"),
    ("face.usd", b"PXR-USDC\x00\x08" + bytes(64), "a USD file"),
    ("face.usda", b"#usda 1.0\n(\n)\n", "a USD file"),
    ("page.html", b"<!DOCTYPE html>\n<html></html>\n", "an HTML page"),
    ("take.mp4", None, "a Live Link Face take")], ids=["glb", "usdc", "usda", "page", "take"])
def test_an_export_or_a_take_where_a_video_belongs_is_named(tmp_path, capsys, name, data, said):
    """One of the tool's own outputs passed on where a video belongs (the walk of chains,
    forty-eighth session: ``transfer --identity-from face.glb``, ``track take.csv``) is named
    as ``probe`` names it. Before: "not a video OpenCV can decode" (a glb, a binary USD
    file), "a text file" (a take, a .usda, a page)."""
    p = tmp_path / name
    if data is None:
        p.write_text(_take_text(["00:00:00:00.000", "00:00:00:01.000"]))
    else:
        p.write_bytes(data)
    msg = _info_error(p)
    assert f"it is {said}" in msg and "not a video OpenCV" not in msg and "text file" not in msg
    status, err = _cli(["puppet", p, "--out", tmp_path / "out.mp4", "--no-progress"], capsys)
    assert status == 2 and len(err) == 1 and name in err[0] and said in err[0], err


def test_a_video_whose_frames_are_cut_off_names_it(tmp_path, capsys, quick_model_path):
    """An MP4 with its index first, cut just after the index: its header counts frames, none
    decodes. Before: ``track`` said "the clip has no frames", naming no file."""
    full = tmp_path / "full.mp4"
    _ffmpeg("-f", "lavfi", "-i", "testsrc=size=96x64:rate=25:duration=0.4", "-c:v", "libx264",
            "-pix_fmt", "yuv420p", "-movflags", "+faststart", str(full))
    data = full.read_bytes()
    p = tmp_path / "cut.mp4"
    p.write_bytes(data[:_moov_end(data) + 64])
    status, err = _cli(["track", p, "--model", quick_model_path, "--out", tmp_path / "t.npz",
                        "--no-progress"], capsys)
    assert status == 2 and len(err) == 1, err
    assert "cut.mp4" in err[0] and "damaged, or cut short" in err[0], err


@pytest.mark.parametrize("name", ["half.mp4", "sound.mp4", "notes.mp4"])
def test_probe_of_an_unreadable_video_is_one_line(tmp_path, capsys, data_dir, name):
    """The same causes at the command line: exit status 2, one line naming the file."""
    p = tmp_path / name
    if name == "half.mp4":
        raw = (data_dir / "video" / "face_2.mp4").read_bytes()
        p.write_bytes(raw[:len(raw) // 2])
    elif name == "sound.mp4":
        _ffmpeg("-f", "lavfi", "-i", "sine=frequency=440:duration=0.5", "-c:a", "aac", str(p))
    else:
        p.write_text("not a video\n")
    status, err = _cli(["probe", p], capsys)
    assert status == 2 and len(err) == 1 and name in err[0], err
    assert "not a video OpenCV can decode" not in err[0]



# ------------------------------------------------------------------------------ plates
def test_a_truncated_exr_frame_prints_nothing_to_stdout(tmp_path, capfd):
    """Before: OpenEXR's bindings printed "Warning: Exception raised reading pixel data for
    part 0 - ..." to standard output (before the tool's error; into ``probe --json``'s)."""
    from facetransfer.io.exr import read_exr_image, write_exr

    p = tmp_path / "f.0001.exr"
    write_exr(p, np.random.default_rng(0).random((48, 64, 3)).astype(np.float32))
    p.write_bytes(p.read_bytes()[:-500])
    capfd.readouterr()
    with pytest.raises(VideoError, match="f.0001.exr"):
        read_exr_image(p)
    assert capfd.readouterr().out == ""


def test_what_else_reaches_stdout_meanwhile_is_kept(capsys):
    """The filter drops the library's note only (written in pieces, as the bindings do): a
    line printed meanwhile comes out as it was, in order; nested uses are one filter."""
    import sys

    from facetransfer.io.native_stdout import native_stdout_kept

    print("before")
    with native_stdout_kept():
        print("one")
        with native_stdout_kept():
            sys.stdout.write("Warning: Exception raised ")
            sys.stdout.write("reading pixel data for part 0 - x")
            sys.stdout.write("\n")
            sys.stdout.write("Warning: something else\n")
        print("two", end="")
    print(" after")
    assert capsys.readouterr().out == "before\none\nWarning: something else\ntwo after\n"


@pytest.mark.parametrize("name,head", [("still.png", b"\x89PNG\r\n\x1a\n"),
                                       ("still.jpg", b"\xff\xd8\xff")])
def test_a_damaged_still_is_said_to_be_a_damaged_image(tmp_path, name, head):
    """An image of a real header and nothing after it. Before: "video still.png has no
    frames"."""
    p = tmp_path / name
    p.write_bytes(head + b"\0" * 32)
    assert "cannot read the image" in _info_error(p)


# ------------------------------------------------------------------------------ weights files
@pytest.mark.parametrize("kind,says", [("archive", "an .npz archive, not a single .npy array"),
                                       ("text", "holds <U1 values, not real numbers"),
                                       ("complex", "holds complex128 values"),
                                       ("nan", "got NaN or infinity")])
def test_identity_weights_files_that_are_not_numbers_are_said_so(tmp_path, kind, says):
    """``--identity-weights W.npy``. Before: an archive named .npy had its key names read as
    numbers ("could not convert string to float: 'a'", naming no file), text the same,
    complex numbers lost their imaginary part (a ComplexWarning), NaN was "expected 3 finite
    numbers, got 3"."""
    from facetransfer.transfer import parse_weights

    p = tmp_path / "w.npy"
    if kind == "archive":
        with open(p, "wb") as fh:
            np.savez(fh, a=np.zeros(3))
    else:
        np.save(p, {"text": np.array(["a", "b", "c"]), "complex": np.array([1 + 2j, 0, 0]),
                    "nan": np.array([np.nan, 0, 0])}[kind])
    with pytest.raises(TransferError, match=says) as e:
        parse_weights(str(p), 3)
    assert kind == "nan" or "w.npy" in str(e.value)


@pytest.mark.parametrize("tc", ["99:02:03:00.000", "01:60:00:00.000"])
def test_a_take_timecode_that_is_no_time_of_day_is_refused(tc):
    """Before: ``99:02:03:00`` was read as four days after midnight (a take's frames then
    placed there), minutes past 59 as the next hour."""
    from facetransfer.take import take_seconds

    with pytest.raises(TransferError, match=f"take t.csv's timecode {tc} at row 2 is not a time"):
        take_seconds(["01:00:00:00.000", tc], name="take t.csv")


# ------------------------------------------------------------------------------ truth files
def _truth_arrays(tmp_path) -> dict:
    """The arrays of a small ground-truth file as :func:`facetransfer.synth.write_clip`
    writes them (3 frames, 10 vertices)."""
    from facetransfer.synth import SyntheticTruth, _save_truth

    F, n = 3, 10
    t = SyntheticTruth(25.0, (64, 48), np.tile(np.eye(3), (F, 1, 1)), np.ones(F),
                       np.zeros((F, 2)), {"identity": np.ones((F, 2)),
                                          "expression": np.zeros((F, 3))},
                       np.zeros((F, 68, 2)), np.zeros((F, n, 2)), np.ones((F, n), bool),
                       np.arange(68) % n, {"model_hash": "abc"})
    _save_truth(t, tmp_path / "good.truth.npz")
    with np.load(tmp_path / "good.truth.npz") as z:
        return {k: z[k] for k in z.files}


@pytest.mark.parametrize("key,value,says", [
    ("fps", np.float64("nan"), "fps"),
    ("rotation", np.zeros((0, 3, 3)), "at least one frame"),
    ("frame_size", np.float64(64), "frame_size"),
    ("meta", np.array("[1, 2]"), "meta is a JSON list"),
    ("visible", np.zeros((3, 10)), "visible must be"),
    ("landmark_indices", np.arange(68) + 100, "landmark_indices"),
])
def test_a_damaged_truth_file_is_one_error_naming_it(tmp_path, key, value, says):
    """``texture lift --track CLIP.truth.npz`` reads synth-video's ground truth. Before: an
    fps of NaN and float flags were read, an empty rotation was an IndexError in the lift, a
    frame size of one number a TypeError, a meta that is a JSON list an AttributeError."""
    from facetransfer.synth import load_truth

    arrays = _truth_arrays(tmp_path)
    p = tmp_path / "bad.truth.npz"
    np.savez(p, **{**arrays, key: value})
    with pytest.raises(VideoError, match="bad.truth.npz is not a facetransfer truth file") as e:
        load_truth(p)
    assert says in str(e.value)
    assert load_truth(tmp_path / "good.truth.npz").fps == 25.0


def test_a_damaged_texture_function_file_is_one_error_naming_it(tmp_path):
    """:meth:`TextureFunction.load` of a file cut short and of an ``.npy`` named ``.npz``.
    Before: BadZipFile and TypeError (the loader caught OSError, KeyError, ValueError only)."""
    from facetransfer.texture import TextureFunction
    from facetransfer.texture.base import TextureError

    rng = np.random.default_rng(0)
    good = tmp_path / "tf.npz"
    TextureFunction(rng.random((3, 4, 4, 3)), np.ones((3, 4, 4)), rng.random((3, 2))).save(good)
    cut, npy = tmp_path / "cut.npz", tmp_path / "array.npz"
    cut.write_bytes(good.read_bytes()[:200])
    with open(npy, "wb") as fh:
        np.save(fh, np.zeros(3))
    for p in (cut, npy):
        with pytest.raises(TextureError, match=p.name):
            TextureFunction.load(p)
    assert TextureFunction.load(good).k == 3
