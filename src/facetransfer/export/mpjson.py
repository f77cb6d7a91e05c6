"""Per-frame blendshape scores in MediaPipe Face Landmarker's layout, for tools written against it.

MediaPipe's result per frame (``FaceLandmarkerResult.faceBlendshapes`` in the web API,
``face_blendshapes`` in Python) is a list with one entry per detected face, each a
``Classifications`` object: ``{"categories": [{"index", "score", "categoryName",
"displayName"}, ...], "headIndex", "headName"}``. The categories run ``_neutral`` (index 0) and
then the 51 ARKit names of :data:`facetransfer.arkit.MEDIAPIPE_NAMES` (indices 1-51).

The file written here::

    {"format": "facetransfer-mediapipe-blendshapes", "version": 1, "fps": 25.0,
     "frameSize": [W, H], "source": "clip.mp4", "timecode": "10:00:00:00",
     "frames": [{"frameIndex": 0, "timestampMs": 0.0,
                 "faceBlendshapes": [{"headIndex": -1, "headName": "",
                                      "categories": [{"index": 0, "score": 0.0,
                                                      "categoryName": "_neutral",
                                                      "displayName": ""}, ...]}]}, ...]}

Categories 0-51 carry MediaPipe's indices and names; ``tongueOut`` (which MediaPipe does not
report) follows as index 52. ``_neutral`` has score 0 (facetransfer has no such score). A frame
where the tracker lost the face has an empty ``faceBlendshapes`` list, as MediaPipe gives for a
frame without a face. ``timecode`` (the tracked video's start timecode, as the glb's and
USD's metadata record it) is there only where the video has one.

References
----------
MediaPipe Face Landmarker, web API ``FaceLandmarkerResult`` / ``Classifications`` /
``Category`` (https://developers.google.com/edge/api/mediapipe/js/tasks-vision.facelandmarkerresult).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..arkit import ARKIT_NAMES, MEDIAPIPE_NAMES
from ..io.atomic import write_text_atomic
from .common import ExportError, require_activations, source_name

__all__ = ["CATEGORY_NAMES", "mediapipe_document", "write_mediapipe_json", "read_mediapipe_json"]

#: Category names by index: MediaPipe's 52 (``_neutral`` first), then ``tongueOut``.
CATEGORY_NAMES: tuple[str, ...] = ("_neutral",) + MEDIAPIPE_NAMES + ("tongueOut",)
_SRC = np.array([-1] + [ARKIT_NAMES.index(n) for n in CATEGORY_NAMES[1:]])


def mediapipe_document(track, *, timecode: str | None = None) -> dict:
    """The JSON document (a dict) for ``track``; ``timecode``: the first frame's (the tracked
    video's start timecode), a top-level ``"timecode"`` where given."""
    a = require_activations(track).astype(np.float64)
    frames = []
    for k in range(track.n_frames):
        faces = []
        if not track.lost[k]:
            cats = [{"index": i, "score": (0.0 if j < 0 else round(float(a[k, j]), 7)),
                     "categoryName": n, "displayName": ""}
                    for i, (n, j) in enumerate(zip(CATEGORY_NAMES, _SRC))]
            faces.append({"headIndex": -1, "headName": "", "categories": cats})
        frames.append({"frameIndex": k, "timestampMs": round(1000.0 * k / track.fps, 3),
                       "faceBlendshapes": faces})
    doc = {"format": "facetransfer-mediapipe-blendshapes", "version": 1, "fps": track.fps,
           "frameSize": list(track.frame_size), "source": source_name(track.source)}
    if timecode is not None:
        doc["timecode"] = str(timecode)
    return {**doc, "frames": frames}


def write_mediapipe_json(track, out: str | os.PathLike, *, overwrite: bool = False,
                         timecode: str | None = None) -> Path:
    """Write the MediaPipe-layout JSON (atomically) and return the path (``timecode``: see
    :func:`mediapipe_document`)."""
    text = json.dumps(mediapipe_document(track, timecode=timecode), separators=(",", ":"))
    return write_text_atomic(out, text + "\n", overwrite=overwrite)


def read_mediapipe_json(path: str | os.PathLike) -> np.ndarray:
    """Scores back as ``(F, 52)`` in :data:`ARKIT_NAMES` order (NaN on frames without a face).

    Reads any file in MediaPipe's per-frame layout (categories matched by ``categoryName``).
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
        frames = doc["frames"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ExportError(f"{p} is not a blendshape JSON file ({exc})") from None
    try:
        out = np.full((len(frames), len(ARKIT_NAMES)), np.nan)
        for k, fr in enumerate(frames):
            _read_frame(fr, out[k])
    except (AttributeError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise ExportError(f"{p} is not a blendshape JSON file (frame layout: {exc!r})") from None
    return out


def _read_frame(fr: dict, row: np.ndarray) -> None:
    """One frame of :func:`read_mediapipe_json` into ``row`` (52,): its first face's scores
    (0 for a category it lacks), NaN left where it has no face."""
    faces = fr.get("faceBlendshapes") or []
    if not faces:
        return
    row[:] = 0.0
    for c in faces[0]["categories"]:
        if c["categoryName"] in ARKIT_NAMES:
            row[ARKIT_NAMES.index(c["categoryName"])] = float(c["score"])
