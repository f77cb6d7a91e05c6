"""MediaPipe Face Landmarker (478 points) to iBUG-68 correspondence, as a data table.

Each iBUG-68 point (0-based: jaw 0-16, brows 17-26, nose 27-35, eyes 36-47, mouth 48-67) is
the mean of one or two MediaPipe points. The eye corners, nose tip and mouth corners follow the
correspondences documented with the test data (33->36, 133->39, 362->42, 263->45, 4->30, 61->48,
291->54). The other entries were chosen from MediaPipe's mesh topology (contours of the face oval,
brows, eyes and lips) and checked on two stills with human iBUG-68 annotation
(``stills/breakingbad``, ``stills/takeo``): eyes, nose and lips agree to ~0.02-0.07 of the outer
eye-corner distance; brows are the mean of MediaPipe's upper and lower brow contours (~0.08); the
jaw line is intrinsically ambiguous (a contour, not a point) and gets a low :data:`IBUG_WEIGHTS`.

That table (:data:`MP_TO_IBUG`) is the origin and the fallback. :func:`mediapipe_to_ibug` uses
the *calibrated* correspondence of ``facetransfer/data/mediapipe_ibug.json``: each iBUG point is
an affine combination (weights summing to 1) of its table points and up to 8 nearby MediaPipe
points, solved by ``benchmarks/calibrate_landmarks.py`` (:mod:`facetransfer.track.calibration`)
against the true iBUG vertices of ICT-FaceKit faces painted by the capture benchmark's generator
on a seed stream disjoint from the benchmark's clips; the file records its provenance.
"""

from __future__ import annotations

import json
import logging
from functools import lru_cache
from importlib import resources

import numpy as np

from ..errors import FaceTransferError, ShapeError

log = logging.getLogger(__name__)

__all__ = ["MP_TO_IBUG", "IBUG_WEIGHTS", "REQUIRED_IBUG", "mediapipe_to_ibug", "ibug_names",
           "eye_distance", "table_matrix", "calibrated_matrix", "mapping_matrix",
           "read_correspondence", "CALIBRATION_FILE", "MP_EYE_CONTOURS"]

#: The calibrated correspondence, in the package's data folder.
CALIBRATION_FILE = "mediapipe_ibug.json"

#: MediaPipe indices averaged for each iBUG-68 point (index = iBUG number, 0-based).
MP_TO_IBUG: tuple[tuple[int, ...], ...] = (
    # jaw 0-16 (subject's right ear -> chin -> left ear), symmetric pairs of the face oval
    (127,), (234,), (93,), (132,), (58,), (172,), (150,), (148, 176), (152,),
    (377, 400), (379,), (397,), (288,), (361,), (323,), (454,), (356,),
    # right brow 17-21 (mean of upper and lower brow contour)
    (70, 46), (63, 53), (105, 52), (66, 65), (107, 55),
    # left brow 22-26
    (336, 285), (296, 295), (334, 282), (293, 283), (300, 276),
    # nose bridge 27-30, tip 30 = 4
    (168,), (197,), (5,), (4,),
    # nostrils 31-35
    (98,), (97,), (2,), (326,), (327,),
    # right eye 36-41 (36 outer corner, 39 inner corner)
    (33,), (160,), (158,), (133,), (153,), (144,),
    # left eye 42-47 (42 inner corner, 45 outer corner)
    (362,), (385,), (387,), (263,), (373,), (380,),
    # outer lips 48-59 (48, 54 corners)
    (61,), (39,), (37,), (0,), (267,), (269,), (291,), (321,), (314,), (17,), (84,), (91,),
    # inner lips 60-67
    (78,), (82,), (13,), (312,), (308,), (317,), (14,), (87,),
)

#: MediaPipe's eye contours, per eye (the subject's right, then left): the outer corner, the
#: lower lid outward-in, the inner corner, the upper lid inward-out (16 points an eye).
MP_EYE_CONTOURS: tuple[tuple[int, ...], ...] = (
    (33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246),
    (263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466),
)

#: Reliability of each iBUG point from the detector, used as a weight in fitting (jaw low).
IBUG_WEIGHTS = np.array([0.2] * 17 + [0.6] * 10 + [1.0] * 9 + [1.0] * 12 + [1.0] * 20)

#: iBUG points a user must give for initialisation: eye corners, nose tip, mouth corners (§5.2).
REQUIRED_IBUG = (36, 39, 42, 45, 30, 48, 54)


def eye_distance(points: np.ndarray) -> float:
    """The face's size in the image: the distance of the outer eye corners (iBUG 36, 45), the
    unit the trackers measure residuals and scale priors in.

    Parameters
    ----------
    points : (68, 2) float
        iBUG-68 pixel positions, NaN where a point is missing.

    Returns
    -------
    float
        ``|p_36 - p_45|``; with a corner missing, or the corners within a pixel of each other
        (a degenerate detection), half the longer side of the bounding box of the points that
        are there; 1.0 when that is not more than a pixel either (or no point is there).
    """
    L = np.asarray(points, float)
    if np.all(np.isfinite(L[[36, 45]])):
        d = float(np.linalg.norm(L[36] - L[45]))
        if d > 1.0:
            return d
    ok = np.all(np.isfinite(L), axis=1)
    half_box = float(np.ptp(L[ok], axis=0).max() / 2) if ok.any() else 0.0
    return half_box if half_box > 1.0 else 1.0



def mediapipe_to_ibug(points: np.ndarray) -> np.ndarray:
    """iBUG-68 points from MediaPipe's 478 (or 468) face landmarks.

    Each iBUG point is a fixed affine combination of MediaPipe points (:func:`mapping_matrix`:
    the calibrated correspondence, weights summing to 1), so the mapping commutes with any
    affine map of the image.

    Parameters
    ----------
    points : (..., 478, d) or (..., 468, d) float
        MediaPipe landmarks (any trailing coordinates, e.g. pixel x, y[, z]).

    Returns
    -------
    (..., 68, d) float64
        NaN where the input is NaN (no face).
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim < 2 or P.shape[-2] < 468:
        raise ShapeError(f"MediaPipe landmarks must be (..., 478, d), got {P.shape}")
    A = mapping_matrix(P.shape[-2])                                        # (68, n)
    if np.isfinite(P).all():          # a face in every frame: nan_to_num's copy, unchanged
        return np.einsum("im,...md->...id", A, np.array(P, copy=True))
    out = np.einsum("im,...md->...id", A, np.nan_to_num(P))
    unknown = np.einsum("im,...m->...i", A != 0, np.isnan(P).any(axis=-1)) > 0
    out[unknown] = np.nan  # an iBUG point is unknown when any of its MediaPipe points is
    return out


def mapping_matrix(n: int) -> np.ndarray:
    """(68, n) weights of :func:`mediapipe_to_ibug`: the calibrated ones
    (:func:`calibrated_matrix`), or the table's (:func:`table_matrix`) when the data file cannot
    be read."""
    try:
        return calibrated_matrix(n)
    except (OSError, FaceTransferError) as exc:
        _warn_fallback(str(exc))
        return table_matrix(n)


@lru_cache(maxsize=1)
def _warn_fallback(reason: str) -> None:
    log.warning("using the uncalibrated MediaPipe-to-iBUG table: %s", reason)


@lru_cache(maxsize=2)
def table_matrix(n: int) -> np.ndarray:
    """(68, n) matrix averaging the MediaPipe points of each iBUG point (:data:`MP_TO_IBUG`)."""
    A = np.zeros((68, n))
    for i, idx in enumerate(MP_TO_IBUG):
        A[i, list(idx)] = 1.0 / len(idx)
    A.setflags(write=False)
    return A


@lru_cache(maxsize=2)
def calibrated_matrix(n: int) -> np.ndarray:
    """(68, n) calibrated weights from the package's ``mediapipe_ibug.json`` (module notes);
    see :func:`read_correspondence`."""
    return read_correspondence(resources.files("facetransfer") / "data" / CALIBRATION_FILE, n)


def read_correspondence(path, n: int) -> np.ndarray:
    """(68, n) weight matrix of a correspondence file (``{"points": [{"ibug": i, "mediapipe":
    [j, ...], "weights": [w, ...]}, ...]}``, written by ``benchmarks/calibrate_landmarks.py``).

    Raises
    ------
    OSError
        When the file cannot be read.
    FaceTransferError
        When it is malformed: not 68 distinct rows, an index outside ``0..n-1`` or a row not
        summing to 1.
    """
    try:
        rows = json.loads(path.read_text())["points"]
    except (ValueError, KeyError, TypeError) as exc:
        raise FaceTransferError(f"{path} is not a correspondence file ({exc})") from None
    if not isinstance(rows, list) or len(rows) != 68:
        raise FaceTransferError(f"{path} must list 68 iBUG points")
    A = np.zeros((68, n))
    seen = set()
    for row in rows:
        try:
            i, idx = int(row["ibug"]), np.asarray(row["mediapipe"], np.int64)
            w = np.asarray(row["weights"], np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise FaceTransferError(f"{path}: bad row {row!r} ({exc})") from None
        if not (0 <= i < 68 and i not in seen and idx.ndim == 1 and idx.shape == w.shape
                and idx.size and idx.min() >= 0 and idx.max() < n
                and np.isfinite(w).all() and abs(w.sum() - 1.0) < 1e-6):
            raise FaceTransferError(f"{path}: iBUG point {i} must appear once, with weights "
                                    f"summing to 1 over MediaPipe indices 0..{n - 1}")
        seen.add(i)
        A[i, idx] = w
    A.setflags(write=False)
    return A


def ibug_names() -> tuple[str, ...]:
    """Short names of the iBUG-68 points (for messages)."""
    names = ([f"jaw{i}" for i in range(17)] + [f"brow{i}" for i in range(10)]
             + [f"nose{i}" for i in range(9)] + [f"eye{i}" for i in range(12)]
             + [f"mouth{i}" for i in range(20)])
    names[36], names[39] = "right outer eye corner", "right inner eye corner"
    names[42], names[45] = "left inner eye corner", "left outer eye corner"
    names[30], names[48], names[54] = "nose tip", "right mouth corner", "left mouth corner"
    return tuple(names)
