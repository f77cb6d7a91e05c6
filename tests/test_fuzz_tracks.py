"""Broken and odd track files (``TRACK.npz``) at :meth:`Track.load` and at the commands that
read one: each is one :class:`~facetransfer.errors.TrackError` naming the file (exit status 2,
one line), never another exception, a pickle loaded, or a track read into a wrong result.

Each case was found by fuzzing (the forty-fifth session): the "before" of each is in its
docstring.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facetransfer.errors import TrackError
from facetransfer.track.result import Track

F = 4


def _track(**over) -> Track:
    """A valid track of ``F`` frames (rotations about y), its fields replaced by ``over``."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    fields = dict(fps=25.0, frame_size=(64, 48),
                  rotation=Rotation.from_euler("y", np.linspace(-0.3, 0.3, F)[:, None]).as_matrix(),
                  scale=np.ones(F), translation=rng.random((F, 2)),
                  weights={"identity": np.ones((F, 2)), "expression": rng.random((F, 3))},
                  landmarks2d=rng.random((F, 68, 2)), confidence=np.full(F, 0.9),
                  lost=np.zeros(F, bool), model_hash="abc", mode_names=("identity", "expression"),
                  source="clip.mp4")
    fields.update(over)
    return Track(**fields)


@pytest.fixture(scope="module")
def arrays(tmp_path_factory) -> dict:
    p = _track().save(tmp_path_factory.mktemp("tracks") / "good.npz")
    with np.load(p) as z:
        return {k: z[k] for k in z.files}


def _write(path: Path, arrays: dict) -> Path:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())
    return path


def _refused(path: Path, says: str) -> str:
    with pytest.raises(TrackError) as e:
        Track.load(path)
    msg = str(e.value)
    assert path.name in msg and says in msg, msg
    assert msg.count(str(path)) == 1, f"the file is named more than once: {msg}"
    return msg


#: (case, key, value, words of the message). Before, each of these loaded.
BAD = [
    ("version 0", "format_version", np.int64(0), "versions start at 1"),
    ("negative version", "format_version", np.int64(-5), "versions start at 1"),
    ("zero rotation", "rotation", np.zeros((F, 3, 3)), "rotation of frame 0 is not a rotation"),
    ("scaled rotation", "rotation", np.tile(2 * np.eye(3), (F, 1, 1)), "not a rotation"),
    ("mirror", "rotation", np.tile(np.diag([1.0, 1.0, -1.0]), (F, 1, 1)), "not a rotation"),
    ("fps 1e-300", "fps", np.float64(1e-300), "fps must lie in"),
    ("fps 1e300", "fps", np.float64(1e300), "fps must lie in"),
    ("frame size 200000", "frame_size", np.array([200000, 200000]), "frame_size must be"),
    ("lost 0.5", "lost", np.full(F, 0.5), "'lost' must hold flags"),
    ("shot start 1.5", "shot_starts", np.array([1.5]), "whole frame numbers"),
    ("mode named twice", "mode_names", np.array(["identity", "identity"]), "repeat a name"),
    ("source a number", "source", np.float64(3.0), "'source' must hold text"),
]


@pytest.mark.parametrize("case,key,value,says", BAD, ids=[b[0] for b in BAD])
def test_a_track_file_of_wrong_values_is_refused_naming_it(tmp_path, arrays, case, key, value,
                                                          says):
    """Before: read. The renderer then refused a non-rotation without naming the track (a
    scaled one was exported as head angles), ffmpeg failed on 1e300 fps, lost 0.5 was True,
    shot start 1.5 was frame 1, a repeated mode name passed."""
    _refused(_write(tmp_path / "bad.npz", {**arrays, key: value}), says)


@pytest.mark.parametrize("key,value", [("lost", np.array([0, 1, 0, 1])),
                                       ("shot_starts", np.array([2.0])),
                                       ("rotation", None)], ids=["lost 0/1", "whole float",
                                                                 "rotation 1e-9 off"])
def test_near_misses_still_load(tmp_path, arrays, key, value):
    """What the checks above let through: flags as 0/1, a whole frame number stored as a float,
    a rotation off by rounding (1e-9); read as the same values."""
    if value is None:
        value = arrays["rotation"] + 1e-9
    t = Track.load(_write(tmp_path / "near.npz", {**arrays, key: value}))
    if key == "lost":
        assert t.lost.tolist() == [False, True, False, True]
    elif key == "shot_starts":
        assert t.shot_starts == (2,)
    else:
        np.testing.assert_allclose(t.rotation, value, atol=0)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=st.lists(st.floats(-2, 2, allow_nan=False), min_size=9, max_size=9))
def test_every_rotation_a_track_file_yields_is_one(tmp_path, arrays, m):
    """Property: whatever 3x3 matrix a file holds on frame 2, a track that loads holds
    rotations (R Rᵀ = I to 1e-4, det +1); otherwise one TrackError naming the frame."""
    R = arrays["rotation"].copy()
    R[2] = np.reshape(m, (3, 3))
    p = _write(tmp_path / "rot.npz", {**arrays, "rotation": R})
    try:
        t = Track.load(p)
    except TrackError as exc:
        assert "frame 2" in str(exc) and p.name in str(exc)
        return
    Rt = t.rotation[2]
    assert np.abs(Rt @ Rt.T - np.eye(3)).max() <= 1e-4 and np.linalg.det(Rt) > 0


_UNPICKLED: list = []


class _Marker:
    """Records its unpickling: a file that unpickled it ran code from the file."""

    def __reduce__(self):
        return (_UNPICKLED.append, ("unpickled",))


def test_a_pickle_inside_a_track_file_is_never_loaded(tmp_path, arrays):
    """A member holding a pickle, as an object array and as raw pickle bytes under an
    ``.npy`` name: refused naming the file, the pickle not run. Before, the raw member reached
    the checks as ``bytes`` (numpy hands over a member without the ``.npy`` header as such):
    AttributeError, a traceback from every command."""
    obj = np.empty(1, object)
    obj[0] = _Marker()
    _refused(_write(tmp_path / "objects.npz", {**arrays, "scale": obj}), "not an .npz archive")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for k, v in arrays.items():
            if k != "scale":
                b = io.BytesIO()
                np.save(b, v)
                zf.writestr(k + ".npy", b.getvalue())
        zf.writestr("scale.npy", pickle.dumps(_Marker()))
    raw = tmp_path / "raw.npz"
    raw.write_bytes(buf.getvalue())
    _refused(raw, "scale are not .npy arrays")
    assert _UNPICKLED == []


def test_a_message_names_the_file_once(tmp_path, arrays):
    """Before: "track file X is invalid: track file X: source_first_frame/...". """
    msg = _refused(_write(tmp_path / "first.npz", {**arrays, "source_first_frame": np.int64(-5),
                                                    "source_timecode": np.array("")}),
                   "source_first_frame")
    assert "is invalid: track file" not in msg


# ------------------------------------------------------------------------------ commands
def _cli(argv, capsys) -> tuple[int, list[str]]:
    from facetransfer.cli.main import main

    status = main([str(a) for a in argv])
    return status, [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def bad_tracks(tmp_path_factory, arrays) -> dict:
    d = tmp_path_factory.mktemp("bad")
    out = {"raw": d / "raw.npz", "npy": d / "array.npz"}
    with zipfile.ZipFile(out["raw"], "w") as zf:     # every array, "scale" not one
        for k, v in arrays.items():
            b = io.BytesIO()
            np.save(b, v)
            zf.writestr(k + ".npy", b.getvalue() if k != "scale" else b"not an array")
    np.save(d / "array.npy", np.zeros(3))
    (d / "array.npy").rename(out["npy"])
    far = arrays["scale"].copy()
    far[2] = 1e300
    out["far"] = _write(d / "far.npz", {**arrays, "scale": far})
    return out


@pytest.mark.parametrize("bad", ["raw", "npy", "far"])
@pytest.mark.parametrize("command", ["export", "edit", "probe", "puppet", "transfer"])
def test_commands_given_a_bad_track_say_one_line(tmp_path, capsys, bad_tracks, quick_model_path,
                                                 data_dir, command, bad):
    """Exit status 2 and one line naming the track, at every command that reads one. Before:
    a member that is not an array was an AttributeError traceback everywhere, an ``.npy``
    named ``.npz`` a TypeError traceback from ``probe``."""
    t, M, clip = bad_tracks[bad], quick_model_path, data_dir / "video" / "face_2.mp4"
    argv = {"export": ["export", t, "--format", "livelink", "--out", tmp_path / "o.csv"],
            "edit": ["edit", t, "--model", M, "--scale", "smile=1.5", "--out", tmp_path / "e.npz"],
            "probe": ["probe", t],
            "puppet": ["puppet", clip, "--model", M, "--track", t, "--out", tmp_path / "p.mp4"],
            "transfer": ["transfer", "--target", clip, "--target-track", t, "--expression-from",
                         clip, "--source-track", t, "--model", M, "--out", tmp_path / "t.mp4"],
            }[command]
    status, err = _cli(argv, capsys)
    assert status == 2 and len(err) == 1, err
    assert err[0].startswith(f"facetransfer {command}: error: ") and t.name in err[0], err
    if bad == "far":      # before: rendered (puppet: an empty frame), or refused for its length
        assert "scale of frame 2 is 1e+300, outside [6.4e-05, 64000]" in err[0], err


def test_a_member_declaring_more_data_than_it_holds_is_damage_not_memory(tmp_path, arrays):
    """A header flipped to claim 10^11 numbers (745 GiB) in a file of kilobytes. Before:
    MemoryError, which the commands say as "out of memory (the job is too large for this
    machine)"."""
    from facetransfer.errors import ModelFileError
    from facetransfer.model import load_model

    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False,
                                               "shape": (10**11,)})
    p = tmp_path / "claims.npz"
    with zipfile.ZipFile(p, "w") as zf:
        for k, v in arrays.items():
            b = io.BytesIO()
            np.save(b, v)
            zf.writestr(k + ".npy", b.getvalue() if k != "scale" else head.getvalue() + b"\0" * 64)
    _refused(p, "member(s) scale declare more data than they hold")
    with pytest.raises(ModelFileError, match="claims.npz is damaged"):
        load_model(p)


def test_blendshapes_beyond_float32_are_refused_without_a_warning(tmp_path, arrays):
    """Before: cast to float32 first, 1e300 gave numpy's "overflow encountered in cast"
    (a warning line before the error) and then the error."""
    import warnings

    from facetransfer.arkit import ARKIT_NAMES

    bs = np.full((F, len(ARKIT_NAMES)), 1e300)
    p = _write(tmp_path / "bs.npz", {**arrays, "blendshapes": bs,
                                     "blendshape_names": np.array(ARKIT_NAMES)})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _refused(p, "blendshapes must be finite and lie in [0, 1]")


#: (key, frame 2's value, words of the message): a value no tracked face holds, or not a
#: number. Before, each loaded (1e300, 1e-300: an empty frame rendered; weights of 1e300:
#: "all triangles are degenerate") or was refused without its frame ("has non-finite values").
FAR = [("scale", 1e300, "scale of frame 2 is 1e+300, outside [6.4e-05, 64000]"),
       ("scale", 1e-300, "scale of frame 2 is 1e-300, outside"),
       ("scale", np.nan, "scale of frame 2 is nan, not a number"),
       ("translation", -1e300, "translation of frame 2 is -1e+300, outside [-6400, 6400]"),
       ("translation", np.nan, "translation of frame 2 is nan, not a number"),
       ("translation", np.inf, "translation of frame 2 is inf, outside"),
       ("landmarks2d", 1e300, "landmarks2d of frame 2 is 1e+300, outside"),
       ("weights_expression", 1e300, "weights_expression of frame 2 is 1e+300, outside "
        "[-1e+06, 1e+06]"),
       ("detections2d", np.inf, "detections2d of frame 2 is inf, outside")]


@pytest.mark.parametrize("key,value,says", FAR, ids=[f"{k} {v}" for k, v, _ in FAR])
def test_a_pose_no_tracked_face_holds_is_refused_naming_key_and_frame(tmp_path, arrays, key,
                                                                       value, says):
    """Bounds from the tracker's own tracks (``SCALE_SIDES``, ``PIXEL_SIDES``,
    ``WEIGHT_LIMIT``: 0.025-0.040 sides of scale, positions within 1.04 sides, weights within
    12, on the data folder's clips), the key and the frame named."""
    a = dict(arrays)
    if key == "detections2d":
        a[key] = np.full_like(arrays["landmarks2d"], np.nan)        # no face found: allowed
        assert Track.load(_write(tmp_path / "nan.npz", a)).detections2d is not None
    v = a[key].copy()
    v[2] = value
    msg = _refused(_write(tmp_path / "far.npz", {**a, key: v}), says)
    assert "is invalid" not in msg


def test_poses_within_the_bounds_still_load(tmp_path, arrays):
    """A face far off the frame (99 sides), a tiny or huge scale (1e-5, 900 sides), weights of
    9e5, a lost frame: read as they are."""
    scale, tr, w = arrays["scale"].copy(), arrays["translation"].copy(), \
        arrays["weights_expression"].copy()
    scale[1:3] = 64e-5, 64 * 900
    tr[3] = -99 * 64
    w[0, 0] = 9e5
    t = Track.load(_write(tmp_path / "near.npz", {**arrays, "scale": scale, "translation": tr,
                                                  "weights_expression": w,
                                                  "lost": np.array([0, 0, 1, 0])}))
    assert t.scale.tolist() == scale.tolist() and t.translation[3].tolist() == tr[3].tolist()
    assert t.weights["expression"][0, 0] == 9e5
