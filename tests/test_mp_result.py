"""Face Landmarker's results read as arrays (facetransfer.track.mp_result): the same points and
scores as through MediaPipe's own Python objects, frame for frame; the API where the reader
cannot run."""

from __future__ import annotations

import ctypes
from types import SimpleNamespace

import numpy as np
import pytest

from facetransfer.io.video import read_video
from facetransfer.track.detect import VideoLandmarker, detect_clip
from facetransfer.track.init import MediaPipeDetector
from facetransfer.track.mp_result import ArrayReader, array_reader


@pytest.fixture(scope="module")
def frames(data_dir):
    return read_video(data_dir / "video" / "driving_d6.mp4", max_frames=12)[0]


def _through_api(fps: float = 30.0, blendshapes: bool = True) -> VideoLandmarker:
    """A video landmarker read through MediaPipe's Python objects (no array reader)."""
    lm = VideoLandmarker(fps=fps, blendshapes=blendshapes)
    lm._reader = None
    return lm


@pytest.mark.parametrize("blendshapes", [True, False])
def test_the_arrays_are_the_api_objects_values(frames, blendshapes):
    with VideoLandmarker(fps=30.0, blendshapes=blendshapes) as fast, \
            _through_api(blendshapes=blendshapes) as slow:
        assert isinstance(fast._reader, ArrayReader)
        for f in frames:
            (p, s), (q, t) = fast.detect_scored(f), slow.detect_scored(f)
            assert p is not None and p.shape == (478, 2) and p.dtype == np.float64
            assert np.array_equal(p, q)
            if blendshapes:
                assert s.dtype == np.float32 and s.shape == (52,)
                assert np.array_equal(s, t, equal_nan=True)
                assert np.isfinite(s).sum() == 51            # tongueOut is not scored
            else:
                assert s is None and t is None


def test_a_clip_detected_through_the_reader_or_the_api_is_the_same(frames):
    with VideoLandmarker(fps=30.0, blendshapes=True) as fast:
        a = detect_clip(frames, fast, keep478=True, every=2)
    with _through_api() as slow:
        b = detect_clip(frames, slow, keep478=True, every=2)
    for name in ("points", "flow", "points478", "scores", "change"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def test_no_face_gives_none_and_the_clock_moves_on(frames):
    grey = np.full_like(frames[0], 118)
    with VideoLandmarker(fps=30.0, blendshapes=True) as lm:
        assert lm.detect_scored(grey) == (None, None)
        assert lm._i == 1
        p, s = lm.detect_scored(frames[0])
        assert p is not None and s is not None and lm._i == 2


def test_without_the_private_parts_there_is_no_reader(frames, monkeypatch):
    """No reader of a landmarker without MediaPipe's private parts; the image-mode detector,
    and a video landmarker without a reader, detect through the API's objects."""
    import facetransfer.track.detect as detect

    class Landmarker:           # a FaceLandmarker of another MediaPipe: no library handle
        pass

    assert array_reader(Landmarker()) is None

    def no_reader(*args):
        raise AssertionError("read through the array reader")

    monkeypatch.setattr(ArrayReader, "detect_for_video", no_reader)
    with MediaPipeDetector() as det:             # the image-mode detector reads the API's
        assert det.detect_scored(frames[0])[0].shape == (478, 2)
    monkeypatch.setattr(detect, "array_reader", lambda landmarker: None)
    with VideoLandmarker(fps=30.0) as lm:
        assert lm._reader is None and lm.detect_scored(frames[0])[0].shape == (478, 2)


def _landmarker():
    """What :func:`array_reader` reads of a ``FaceLandmarker``: its wrapped library, its
    handle."""
    lib = SimpleNamespace(MpFaceLandmarkerDetectForVideo=print, MpFaceLandmarkerCloseResult=print)
    return SimpleNamespace(_lib=lib, _handle=1)


def _struct(fields) -> type:
    return type("Struct", (ctypes.Structure,), {"_fields_": list(fields)})


def test_a_c_result_of_another_layout_gives_no_reader(monkeypatch):
    """The reader walks the C result through its own fields: a MediaPipe whose result lacks a
    field the reader reads, or whose landmarks or categories are other structs than the ones
    it imports, gives no reader (the API then), not an error at every frame."""
    from mediapipe.tasks.python.vision import face_landmarker as fl

    real = fl.MpFaceLandmarkerResultC
    assert isinstance(array_reader(_landmarker()), ArrayReader)

    def result(drop=(), **change):
        return _struct((n, change.get(n, t)) for n, t in real._fields_ if n not in drop)

    count = ctypes.c_uint32
    double_xy = _struct([("landmarks", ctypes.POINTER(_struct(
        [("x", ctypes.c_double), ("y", ctypes.c_double)]))), ("landmarks_count", count)])
    nameless = _struct([("categories", ctypes.POINTER(_struct(
        [("index", ctypes.c_int), ("score", ctypes.c_float)]))), ("categories_count", count)])
    for other in (result(drop=("face_blendshapes_count",)),
                  result(face_landmarks=ctypes.POINTER(double_xy)),
                  result(face_blendshapes=ctypes.POINTER(nameless)),
                  result(face_landmarks=ctypes.c_void_p), None):
        monkeypatch.setattr(fl, "MpFaceLandmarkerResultC", other)
        assert array_reader(_landmarker()) is None
    monkeypatch.setattr(fl, "MpFaceLandmarkerResultC", result(face_landmarks_count=ctypes.c_int))
    assert isinstance(array_reader(_landmarker()), ArrayReader)   # another integer: read


def test_the_reader_raises_as_the_api_and_closes_every_result(frames, monkeypatch):
    """A timestamp that goes back raises the API's error through the reader (MediaPipe's own
    wrapper of the C call's status), and the reader goes on; each C result is closed: with a
    face, without one, and where reading it fails."""
    with VideoLandmarker(fps=30.0, blendshapes=True) as fast, _through_api() as slow:
        for lm in (fast, slow):
            lm.detect_scored(frames[0])
            lm._i = 0
            with pytest.raises(ValueError, match="monotonically increasing"):
                lm.detect_scored(frames[1])
        lib, closed = fast._lm._lib, []
        real = lib.MpFaceLandmarkerCloseResult
        monkeypatch.setattr(lib, "MpFaceLandmarkerCloseResult",
                            lambda res: closed.append(1) or real(res))
        assert fast.detect_scored(frames[2])[0] is not None
        assert fast.detect_scored(np.full_like(frames[0], 118)) == (None, None)

        def fails(categories):
            raise RuntimeError("read")

        monkeypatch.setattr(fast._reader, "_read_scores", fails)
        with pytest.raises(RuntimeError, match="read"):
            fast.detect_scored(frames[3])
        assert len(closed) == 3
