"""Face Landmarker's video-mode results read as arrays, without its Python objects.

MediaPipe's Tasks API (``FaceLandmarker.detect_for_video``) turns each C result into Python
objects before returning it: 478 ``NormalizedLandmark`` dataclasses and 52 ``Category`` ones,
which the detector (:class:`facetransfer.track.detect.VideoLandmarker`) then reads back into
arrays. On ``driving_d6`` (218 frames shown) that conversion took 0.093 of the 0.18 CPU-s
the main thread spent in the landmarker's calls (BENCHMARKS.md, "Forty-eighth session (helper
track48)").

:class:`ArrayReader` makes the call that ``detect_for_video`` makes (the same C function,
through the landmarker's own wrapped library, so its errors are raised as the API raises them)
and reads the first face's points and blendshape scores from the C result straight into
arrays: the values are the same floats (``float32`` widened to ``float64``, as the API's
Python floats are). :func:`array_reader` gives None where MediaPipe's private parts it uses are
not there (another MediaPipe version): the caller then goes through the API.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ..arkit import ARKIT_NAMES

__all__ = ["ArrayReader", "array_reader"]

#: Column of each ARKit name in the scores (:func:`facetransfer.track.init.blendshape_scores`).
_ARKIT_INDEX = {n: k for k, n in enumerate(ARKIT_NAMES)}


def _fields(struct, names: tuple, formats: tuple) -> np.dtype:
    """A numpy record type reading the fields ``names`` of the ctypes ``struct``."""
    return np.dtype({"names": list(names), "formats": list(formats),
                     "offsets": [getattr(struct, n).offset for n in names],
                     "itemsize": ctypes.sizeof(struct)})


def _records(pointer, count: int, dtype: np.dtype) -> np.ndarray:
    """``count`` C structs at ``pointer`` as records of ``dtype`` (a view: copy before the
    result is closed)."""
    address = ctypes.cast(pointer, ctypes.c_void_p).value
    raw = (ctypes.c_char * (count * dtype.itemsize)).from_address(address)
    return np.frombuffer(raw, dtype, count=count)


class ArrayReader:
    """Reads a video-mode landmarker's results as arrays (see the module notes)."""

    def __init__(self, landmarker, result_type, landmark_type, category_type) -> None:
        self._lm = landmarker
        self._result = result_type
        self._points = _fields(landmark_type, ("x", "y"), ("<f4", "<f4"))
        self._scores = _fields(category_type, ("index", "score"), ("<i4", "<f4"))
        self._index = None          # the categories' indices when ``_columns`` was made
        self._columns = None        # (which categories, their ARKit columns)

    def detect_for_video(self, image, timestamp_ms: int
                         ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(points, scores)`` of the first face in the MediaPipe ``image``: its landmarks in
        normalised image coordinates (N, 2) float64 and its blendshape scores (52,) float32 in
        :data:`facetransfer.arkit.ARKIT_NAMES` order (NaN for a name it did not score), or
        None where there is no face (scores: no face, or a landmarker without blendshapes)."""
        lib, res = self._lm._lib, self._result()  # noqa: SLF001 - see the module notes
        lib.MpFaceLandmarkerDetectForVideo(self._lm._handle, image._image_ptr,  # noqa: SLF001
                                           None, int(timestamp_ms), ctypes.byref(res))
        try:
            if not res.face_landmarks_count:
                return None, None
            lms = res.face_landmarks[0]
            rec = _records(lms.landmarks, int(lms.landmarks_count), self._points)
            pts = np.empty((len(rec), 2), np.float64)
            pts[:, 0], pts[:, 1] = rec["x"], rec["y"]
            scores = None
            if res.face_blendshapes_count:
                scores = self._read_scores(res.face_blendshapes[0])
            return pts, scores
        finally:
            lib.MpFaceLandmarkerCloseResult(ctypes.byref(res))

    def _read_scores(self, categories) -> np.ndarray:
        """One face's categories as :func:`facetransfer.track.init.blendshape_scores` gives
        them; the columns found by the categories' names once, while their indices stay."""
        n = int(categories.categories_count)
        rec = _records(categories.categories, n, self._scores)
        if self._index is None or not np.array_equal(self._index, rec["index"]):
            names = [categories.categories[j].category_name for j in range(n)]
            found = [(j, _ARKIT_INDEX.get(b.decode("utf-8") if b else None))
                     for j, b in enumerate(names)]
            found = [(j, k) for j, k in found if k is not None]
            self._columns = (np.array([j for j, _ in found], np.intp),
                             np.array([k for _, k in found], np.intp))
            self._index = rec["index"].copy()
        out = np.full(len(ARKIT_NAMES), np.nan, np.float32)
        rows, cols = self._columns
        out[cols] = rec["score"][rows]
        return out


def array_reader(landmarker) -> ArrayReader | None:
    """An :class:`ArrayReader` of a ``FaceLandmarker`` in video mode, or None where this
    MediaPipe lacks what it reads (the caller then uses ``detect_for_video``): the library's
    two functions, or a struct or field of the C result as :func:`_layout` finds them."""
    try:
        from mediapipe.tasks.python.vision import face_landmarker
    except ImportError:
        return None
    lib = getattr(landmarker, "_lib", None)
    if lib is None or getattr(landmarker, "_handle", None) is None or \
            not hasattr(lib, "MpFaceLandmarkerDetectForVideo") or \
            not hasattr(lib, "MpFaceLandmarkerCloseResult"):
        return None
    types = _layout(getattr(face_landmarker, "MpFaceLandmarkerResultC", None))
    return None if types is None else ArrayReader(landmarker, *types)


def _layout(result_type) -> tuple | None:
    """``(result_type, landmark_type, category_type)``: the C result's struct and those of
    one landmark and one category, found through the result's own pointer fields (the
    structs its C memory holds), each with every field :class:`ArrayReader` reads, of the
    type it reads it as (a count: any integer); None where one is missing or differs."""
    faces, shapes = _pointee(result_type, "face_landmarks"), _pointee(result_type,
                                                                       "face_blendshapes")
    landmark, category = _pointee(faces, "landmarks"), _pointee(shapes, "categories")
    want = ((result_type, {"face_landmarks_count": int, "face_blendshapes_count": int}),
            (faces, {"landmarks_count": int}), (shapes, {"categories_count": int}),
            (landmark, {"x": ctypes.c_float, "y": ctypes.c_float}),
            (category, {"index": ctypes.c_int, "score": ctypes.c_float,
                        "category_name": ctypes.c_char_p}))
    for struct, fields in want:
        types = _field_types(struct)
        for name, t in fields.items():
            if not (_is_integer(types.get(name)) if t is int else types.get(name) is t):
                return None
    return result_type, landmark, category


def _field_types(struct) -> dict:
    """A ctypes struct's fields, name -> ctypes type ({}: not a struct)."""
    fields = getattr(struct, "_fields_", None) if isinstance(struct, type) else None
    return {f[0]: f[1] for f in fields} if isinstance(fields, (list, tuple)) else {}


def _pointee(struct, name: str):
    """The type the pointer field ``name`` of ``struct`` points to, or None."""
    t = _field_types(struct).get(name)
    return t._type_ if isinstance(t, type) and issubclass(t, ctypes._Pointer) else None


def _is_integer(t) -> bool:
    """Whether ``t`` is one of ctypes' integer types."""
    return isinstance(t, type) and issubclass(t, ctypes._SimpleCData) and \
        t._type_ in "bBhHiIlLqQ"
