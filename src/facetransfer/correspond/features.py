"""Feature points on scans: iBUG-68 keyed JSON files and the paper's marking protocols (§4.2).

File format::

    {"points": {"36": [x, y, z], "45": [x, y, z], ...}, "units": "...", "note": "..."}

Keys are iBUG-68 landmark numbers, 0-based, as strings; any subset of at least
:data:`MIN_FEATURES`; top-level keys other than ``"points"`` are ignored. Coordinates are in the
scan's own units and frame.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError
from ..io.atomic import write_text_atomic

#: Fewest feature points a similarity plus a non-rigid warm start can use robustly.
MIN_FEATURES = 8

#: iBUG-68 landmark groups (0-based), Sagonas et al. 2013 annotation scheme.
IBUG_GROUPS: dict[str, tuple[int, ...]] = {
    "jaw": tuple(range(0, 17)),
    "right_brow": tuple(range(17, 22)),
    "left_brow": tuple(range(22, 27)),
    "nose_bridge": tuple(range(27, 31)),
    "nose_base": tuple(range(31, 36)),
    "right_eye": tuple(range(36, 42)),
    "left_eye": tuple(range(42, 48)),
    "outer_lip": tuple(range(48, 60)),
    "inner_lip": tuple(range(60, 68)),
}
#: Group name of every iBUG-68 landmark, by index.
IBUG_NAMES: tuple[str, ...] = tuple(
    next(g for g, idx in IBUG_GROUPS.items() if i in idx) for i in range(68))

_BROWS = IBUG_GROUPS["right_brow"] + IBUG_GROUPS["left_brow"]
#: Neutral (m-viseme) scans: 42 points (§4.2). The paper does not list them; we take the brows
#: (10), nose bridge top, tip and base corners and middle (27, 30, 31, 33, 35), eyes (12), outer
#: lips (12), and jaw ends and chin (0, 8, 16): 42 points covering the whole face.
PROTOCOL_NEUTRAL_42: tuple[int, ...] = tuple(sorted(
    set(_BROWS) | {27, 30, 31, 33, 35} | set(range(36, 48)) | set(range(48, 60)) | {0, 8, 16}))
#: Other closed-mouth scans: 21 points around the eyebrows and lips (§4.2): brows (10), outer
#: lip corners, peaks and bottom (48, 50, 51, 52, 54, 56, 57, 58), inner lip middles (62, 66) and
#: the nose tip 30.
PROTOCOL_CLOSED_MOUTH_21: tuple[int, ...] = tuple(sorted(
    set(_BROWS) | {48, 50, 51, 52, 54, 56, 57, 58, 62, 66, 30}))
#: Viseme scans: 18 points around the lips (§4.2): the outer lip (12) and the inner lip without
#: its corners 60, 64 (which nearly coincide with 48, 54).
PROTOCOL_VISEME_18: tuple[int, ...] = tuple(range(48, 60)) + (61, 62, 63, 65, 66, 67)
#: Protocol names accepted by :func:`read_features` (``protocol=``).
PROTOCOLS = {"neutral": PROTOCOL_NEUTRAL_42, "closed-mouth": PROTOCOL_CLOSED_MOUTH_21,
             "viseme": PROTOCOL_VISEME_18}


class FeatureError(FaceTransferError):
    """A feature-point file is malformed, too small, or its points are off the scan."""


@dataclass(frozen=True)
class FeaturePoints:
    """Feature points on a scan.

    Attributes
    ----------
    indices : (k,) int64
        iBUG-68 landmark numbers, increasing.
    points : (k, 3) float64
        Their positions on the scan (scan units).
    """

    indices: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.indices)

    def subset(self, indices) -> "FeaturePoints":
        """The points whose landmark numbers are in ``indices`` (missing ones are skipped)."""
        keep = np.isin(self.indices, np.asarray(list(indices), dtype=np.int64))
        return FeaturePoints(self.indices[keep], self.points[keep])


def features_from_dict(points: dict, *, source: str = "features") -> FeaturePoints:
    """Validate a ``{"36": [x, y, z], ...}`` mapping and return :class:`FeaturePoints`.

    Raises
    ------
    FeatureError
        Keys not iBUG-68 numbers 0..67, values not 3 finite numbers, or fewer than 8 points.
    """
    if not isinstance(points, dict):
        raise FeatureError(f"{source}: 'points' must be an object keyed by iBUG-68 number, "
                           f"got {type(points).__name__}")
    idx, pts = [], []
    for key, val in points.items():
        try:
            k = int(str(key).strip())
        except ValueError:
            raise FeatureError(f"{source}: key {key!r} is not an iBUG-68 landmark number 0..67") from None
        if not 0 <= k <= 67:
            raise FeatureError(f"{source}: landmark {k} outside the iBUG-68 range 0..67")
        if k in idx:
            raise FeatureError(f"{source}: landmark {k} given twice")
        try:
            p = np.asarray(val, dtype=np.float64)
        except (TypeError, ValueError):
            raise FeatureError(f"{source}: landmark {k} must be [x, y, z] numbers, got {val!r}") from None
        if p.shape != (3,):
            raise FeatureError(f"{source}: landmark {k} must be [x, y, z], got shape {p.shape}")
        if not np.all(np.isfinite(p)):
            raise FeatureError(f"{source}: landmark {k} has NaN or infinite coordinates")
        idx.append(k)
        pts.append(p)
    if len(idx) < MIN_FEATURES:
        raise FeatureError(f"{source}: {len(idx)} feature points, at least {MIN_FEATURES} needed")
    order = np.argsort(idx)
    return FeaturePoints(np.asarray(idx, dtype=np.int64)[order], np.asarray(pts)[order])


def read_features(path: str | os.PathLike, *, protocol: str | None = None) -> FeaturePoints:
    """Read a feature-point JSON file.

    Parameters
    ----------
    path : path-like
    protocol : {"neutral", "closed-mouth", "viseme"}, optional
        Keep only that protocol's points (§4.2: 42, 21 or 18 points); at least 8 must be present.

    Raises
    ------
    FeatureError
        Unreadable file, invalid JSON, no ``"points"`` object, or bad entries.
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except OSError as exc:
        raise FeatureError(f"cannot read feature file {p}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FeatureError(f"feature file {p} is not valid JSON: {exc}") from None
    if not isinstance(data, dict) or "points" not in data:
        raise FeatureError(f"feature file {p} has no 'points' object")
    fp = features_from_dict(data["points"], source=str(p))
    if protocol is not None:
        if protocol not in PROTOCOLS:
            raise FeatureError(f"unknown protocol {protocol!r}; expected one of {sorted(PROTOCOLS)}")
        fp = fp.subset(PROTOCOLS[protocol])
        if len(fp) < MIN_FEATURES:
            raise FeatureError(f"{p}: only {len(fp)} points of the {protocol} protocol, "
                               f"at least {MIN_FEATURES} needed")
    return fp


def write_features(path: str | os.PathLike, features: FeaturePoints, *, extra: dict | None = None,
                   overwrite: bool = True) -> Path:
    """Write feature points as JSON (atomically); ``extra`` adds top-level keys (notes, units)."""
    data = dict(extra or {})
    data["points"] = {str(int(k)): [round(float(x), 6) for x in p]
                      for k, p in zip(features.indices, features.points)}
    return write_text_atomic(path, json.dumps(data, indent=1) + "\n", overwrite=overwrite)


def validate_features_on_surface(features: FeaturePoints, distance: np.ndarray, *,
                                 rel_tol: float = 0.2, source: str = "features") -> None:
    """Check that feature points lie on the scan.

    Parameters
    ----------
    features : FeaturePoints
    distance : (k,) float
        Distance of each point to the scan surface (scan units).
    rel_tol : float
        Largest allowed distance as a fraction of the feature spread (RMS distance of the points
        from their centroid).

    Raises
    ------
    FeatureError
        Naming the worst landmark, its distance and the tolerance.
    """
    spread = float(np.sqrt(np.mean(np.sum((features.points - features.points.mean(0)) ** 2, 1))))
    if spread <= 0:
        raise FeatureError(f"{source}: all feature points coincide")
    tol = rel_tol * spread
    d = np.asarray(distance, dtype=np.float64)
    bad = np.flatnonzero(d > tol)
    if bad.size:
        w = bad[np.argmax(d[bad])]
        raise FeatureError(f"{source}: {bad.size} feature points are off the scan surface; landmark "
                           f"{int(features.indices[w])} is {d[w]:.4g} away (tolerance {tol:.4g} = "
                           f"{rel_tol:g} x feature spread)")
