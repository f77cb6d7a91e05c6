"""Occluded face regions: a hand over the mouth, dark glasses or bars over the eyes.

Beyond the paper. Face Landmarker places a hidden mouth or hidden eyes by the face's shape and
scores them as if it saw them (a box over the mouth reads as a pucker, black bars over the eyes
as half-closed lids), with full confidence. This module tells, per frame, whether each region
(the mouth, the right eye, the left eye: :data:`REGIONS`) looks as the clip's own frames show
it, from the frame and the region's iBUG-68 points alone.

**The test.** Each region has a fixed set of sample points placed relative to its landmarks
(:func:`region_points`): for the mouth, points across the lips' band (between the outer and the
inner contour, so an open mouth's teeth and tongue are not sampled) and a ring of skin about
them; for an eye, a ring about the eye between the brow and the cheek (the lids' skin and the
skin under the eye, never the eye's opening, so a blink is not sampled). Each point's colour is
read (CIE L*a*b*, the frame blurred by a face-sized kernel) and compared with the point's
median over the clip (its appearance where it was seen, the clip being mostly uncovered); a
point differs where its chroma moves by more than :data:`CHROMA_STEP` or its lightness by more
than :data:`LIGHT_STEP` (shading moves lightness more than chroma, a head turn or a shadow
more than a smile). A region's score is the fraction of its points that differ; a region is
occluded where the score is at least :data:`OCCLUDED_SCORE` for at least :data:`MIN_RUN`
frames in a row.

**Black-and-white clips.** Where the clip has no colour (:func:`facetransfer.monochrome.
is_monochrome` of its frames: three equal channels), chroma tells nothing and a hand's grey is
within the lightness step of the skin's; there a point also differs where its texture (the
lightness' gradient, averaged over a quarter of the eyes' distance: the lips' edges, the lids'
folds, a box's flat inside) is outside :data:`TEXTURE_LOW` to :data:`TEXTURE_HIGH` times its
median over the clip. A colour clip's test is as it was, to the bit.

The clip's median is its own reference: a clip covered in half its frames or more has the
covered look as its median and is not flagged (said in README).

**What follows.** :func:`hold_occluded` (``track --occluders``) bridges a covered region's
ARKit activations over its frames, as the gaze is bridged over a blink
(:mod:`facetransfer.track.gaze`), lowers the confidence there and records the frames
(``Track.occluded``); a transfer onto a target whose track records them keeps the target's
own pixels over the covered regions (:func:`covered_alpha`,
:func:`facetransfer.rewrite_clip._keep_covered`). Figures: BENCHMARKS.md, "Fifty-third
session (helper occl53)".

References
----------
Vlasic et al. 2005 §5 (the tracker this guards); the iBUG-68 landmark layout (Sagonas et al.
2013).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..arkit import activation_basis

#: The regions tested, in the columns' order.
REGIONS = ("mouth", "right_eye", "left_eye")

#: A sample point's chroma (a*, b*) step, in L*a*b* units (OpenCV's 8-bit scale), that differs.
CHROMA_STEP = 9.0
#: A sample point's lightness step (8-bit L*) that differs.
LIGHT_STEP = 45.0
#: In a black-and-white clip: a point's texture, as a fraction of its median over the clip,
#: below this or above :data:`TEXTURE_HIGH` differs (module notes).
TEXTURE_LOW = 0.35
#: (and above this)
TEXTURE_HIGH = 2.5
#: Texture below this (L* units per pixel) is taken as this: a flat point's ratio is not noise's.
TEXTURE_FLOOR = 0.05
#: The fraction of a region's points that differ for the frame's region to be occluded.
OCCLUDED_SCORE = 0.5
#: Frames in a row a region must be found covered for (a shorter run is a glint or a glitch).
MIN_RUN = 4
#: Gaps of at most this many frames between covered frames are closed (a landmark's jump).
MAX_GAP = 2
#: A covered run grows over the frames beside it scoring at least this (an occluder sliding
#: in or out covers part of the region: the detector is misled before the score is high).
EDGE_SCORE = 0.15
#: And then by this many frames each way (the capture's temporal terms carry a misreading on).
MARGIN = 2

# outer lips 48-59 and the inner contour point each faces (60-67)
_INNER_OF = np.array([60, 61, 61, 62, 63, 63, 64, 65, 65, 66, 67, 67])


@dataclass(frozen=True)
class Occlusion:
    """Per-frame occlusion of a clip's face regions.

    Attributes
    ----------
    score : (F, 3) float64 in [0, 1]
        Per frame and region (:data:`REGIONS`), the fraction of its sample points whose colour
        is not the clip's; NaN where no points were given (the face lost).
    occluded : (F, 3) bool
        Where the region is taken as covered (module notes).
    """

    score: np.ndarray
    occluded: np.ndarray

    def frames(self, region: str) -> np.ndarray:
        """The frames where ``region`` (one of :data:`REGIONS`) is covered, as indices."""
        return np.flatnonzero(self.occluded[:, REGIONS.index(region)])


def region_points(points: np.ndarray) -> list[np.ndarray]:
    """The sample points of each region (:data:`REGIONS`) in the frame, from its iBUG-68 points.

    Parameters
    ----------
    points : (68, 2) float64
        iBUG-68 points in pixels ``(x, y)``.

    Returns
    -------
    list of (n, 2) float64
        Per region, its sample points; the same count for every frame.
    """
    p = np.asarray(points, dtype=np.float64)
    outer = p[48:60]
    inner = p[_INNER_OF]
    centre = outer.mean(axis=0)
    band = [outer + s * (inner - outer) for s in (0.3, 0.5)]
    ring = [centre + f * (outer - centre) for f in (1.3, 1.6)]
    mouth = np.concatenate(band + ring)
    return [mouth, _eye_ring(p[36:42], p[17:22]), _eye_ring(p[42:48], p[22:27])]


def _eye_ring(eye: np.ndarray, brow: np.ndarray) -> np.ndarray:
    """Points about one eye: the lids' skin toward the brow, the corners, the skin under it."""
    centre = eye.mean(axis=0)
    width = np.linalg.norm(eye[3] - eye[0])
    down = np.array([0.0, 1.0]) * width
    upper = [0.5 * (brow[0] + eye[0])]
    upper += [eye[k] + s * (brow[k] - eye[k]) for s in (0.35, 0.6) for k in (1, 2, 3)]
    outer = [eye[0] + 0.25 * (eye[0] - centre), eye[3] + 0.25 * (eye[3] - centre)]
    under = [eye[k] + f * down for f in (0.3, 0.5) for k in (5, 4)]
    return np.array(upper + outer + under)


def frame_samples(frame: np.ndarray, points: np.ndarray, texture: bool = False
                  ) -> list[np.ndarray]:
    """The L*a*b* colours of each region's sample points in one frame (and their texture).

    Parameters
    ----------
    frame : (H, W, 3) uint8
        RGB.
    points : (68, 2) float64
        The frame's iBUG-68 points in pixels.
    texture : bool
        Also each point's texture (:func:`_texture`), a fourth column.

    Returns
    -------
    list of (n, 3) or (n, 4) float32
        Per region (:data:`REGIONS`), L*, a*, b* on OpenCV's 8-bit scale (and the texture);
        NaN outside the frame.
    """
    pts = region_points(points)
    allp = np.concatenate(pts)
    h, w = frame.shape[:2]
    eyes = np.linalg.norm(points[42:48].mean(0) - points[36:42].mean(0))
    pad = int(max(4.0, eyes * 0.2))              # (the texture's window: within it)
    x0, y0 = np.floor(allp.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(allp.max(axis=0)).astype(int) + pad
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    k = 4 if texture else 3
    out = [np.full((len(q), k), np.nan, np.float32) for q in pts]
    if x1 - x0 < 2 or y1 - y0 < 2:
        return out
    crop = cv2.cvtColor(np.ascontiguousarray(frame[y0:y1, x0:x1]), cv2.COLOR_RGB2LAB)
    sigma = max(1.0, eyes / 40.0)
    lab = cv2.GaussianBlur(crop.astype(np.float32), (0, 0), sigma)
    xy = (allp - (x0, y0)).astype(np.float32)
    got = cv2.remap(lab, xy[None, :, 0], xy[None, :, 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan,) * 3)[0]
    if texture:
        tex = cv2.remap(_texture(lab[..., 0], eyes), xy[None, :, 0], xy[None, :, 1],
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        got = np.concatenate([got, tex.reshape(-1, 1)], axis=1)
    inside = (allp[:, 0] >= 0) & (allp[:, 0] < w) & (allp[:, 1] >= 0) & (allp[:, 1] < h)
    got[~inside] = np.nan
    n = np.cumsum([0] + [len(q) for q in pts])
    return [got[n[k]:n[k + 1]] for k in range(len(pts))]


def _texture(light: np.ndarray, eyes: float) -> np.ndarray:
    """(h, w) float32: the lightness' gradient magnitude (L* units per pixel), averaged over
    a square of a quarter of the eyes' distance (a box filter: a Gaussian that wide cost 1 ms
    a frame): high on the lips' edges and the lids' folds, low on smooth skin, none on a flat
    occluder."""
    gx = cv2.Sobel(light, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(light, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    side = max(3, int(round(eyes / 4.0)) | 1)
    return cv2.blur(cv2.magnitude(gx, gy), (side, side))


def occlusion_scores(samples: list, grey: bool = False) -> np.ndarray:
    """Per frame and region, the fraction of sample points whose colour is not the clip's.

    Parameters
    ----------
    samples : list of (list of (n, 3) or (n, 4) float32) or None
        Per frame, :func:`frame_samples`' result; None where the face is lost.
    grey : bool
        The clip is black and white: a point's texture (the samples' fourth column) differs
        too (module notes).

    Returns
    -------
    (F, 3) float64
        NaN where the face is lost.
    """
    F = len(samples)
    score = np.full((F, len(REGIONS)), np.nan)
    seen = [i for i, s in enumerate(samples) if s is not None]
    if not seen:
        return score
    for r in range(len(REGIONS)):
        lab = np.stack([samples[i][r] for i in seen]).astype(np.float64)  # (f, n, 3 or 4)
        ref = np.full(lab.shape[1:], np.nan)                                # (n, 3 or 4)
        known = np.isfinite(lab).any(axis=(0, 2))   # a point outside every frame: no median
        ref[known] = np.nanmedian(lab[:, known], axis=0)
        d = lab[..., :3] - ref[:, :3]
        chroma = np.hypot(d[..., 1], d[..., 2])
        differs = (chroma > CHROMA_STEP) | (np.abs(d[..., 0]) > LIGHT_STEP)
        if grey:
            floor = np.maximum(ref[:, 3], TEXTURE_FLOOR)
            ratio = np.maximum(lab[..., 3], TEXTURE_FLOOR) / floor
            differs |= (ratio < TEXTURE_LOW) | (ratio > TEXTURE_HIGH)
        valid = np.isfinite(d).all(axis=2)
        counted = np.maximum(valid.sum(axis=1), 1)
        score[seen, r] = (differs & valid).sum(axis=1) / counted
    return score


def occluded_runs(score: np.ndarray, *, threshold: float = OCCLUDED_SCORE,
                  min_run: int = MIN_RUN, max_gap: int = MAX_GAP) -> np.ndarray:
    """Where each region's score is at least ``threshold`` for ``min_run`` frames in a row.

    Gaps of at most ``max_gap`` frames between such frames are closed first; each run found
    is then grown (:data:`EDGE_SCORE`, :data:`MARGIN`).

    Parameters
    ----------
    score : (F, R) float64
        :func:`occlusion_scores`' result (NaN: not counted, breaks a run).

    Returns
    -------
    (F, R) bool
    """
    hit = np.nan_to_num(score, nan=0.0) >= threshold
    out = np.zeros_like(hit)
    for r in range(hit.shape[1]):
        col = hit[:, r].copy()
        for a, b in _runs(~col):
            if 0 < a and b < len(col) and b - a <= max_gap:
                col[a:b] = True
        for a, b in _runs(col):
            if b - a >= min_run:
                out[_grown(score[:, r], a, b), r] = True
    return out


def _grown(score: np.ndarray, a: int, b: int) -> slice:
    """The run ``[a, b)`` grown over its neighbours scoring :data:`EDGE_SCORE`, then by
    :data:`MARGIN` frames each way, within the clip."""
    edge = np.nan_to_num(score, nan=0.0) >= EDGE_SCORE
    while a > 0 and edge[a - 1]:
        a -= 1
    while b < len(score) and edge[b]:
        b += 1
    return slice(max(a - MARGIN, 0), min(b + MARGIN, len(score)))


def _runs(col: np.ndarray) -> list[tuple[int, int]]:
    """The ``[start, stop)`` spans where a boolean column is True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], col.astype(np.int8), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def clip_occlusion(frames, points: np.ndarray) -> Occlusion:
    """The occlusion of a clip's regions (module notes).

    Parameters
    ----------
    frames : iterable of (H, W, 3) uint8
        The clip's frames, RGB, in order.
    points : (F, 68, 2) float64
        Per frame the iBUG-68 points in pixels (a capture track's ``detections2d``, else its
        ``landmarks2d``); NaN where the face is lost.

    Returns
    -------
    Occlusion
    """
    from ..monochrome import frame_is_monochrome, monochrome_picks

    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (68, 2):
        raise ValueError(f"points must be (F, 68, 2), got {points.shape}")
    picks = set(monochrome_picks(len(points)).tolist())    # the first frame among them
    grey = len(picks) > 0
    samples = []
    for i, frame in enumerate(frames):
        if i >= len(points):
            break
        if i in picks:       # a colour frame: the clip is not grey, no texture needed
            grey = grey and frame_is_monochrome(frame)
        p = points[i]
        samples.append(frame_samples(frame, p, texture=grey) if np.isfinite(p).all()
                       else None)
    samples += [None] * (len(points) - len(samples))
    if not grey:                                  # (a clip grey at first, in colour later)
        samples = [None if s is None else [q[:, :3] for q in s] for s in samples]
    score = occlusion_scores(samples, grey=grey)
    return Occlusion(score=score, occluded=occluded_runs(score))


#: A frame's confidence is multiplied by this where any of its regions is covered.
COVERED_CONFIDENCE = 0.5


def region_columns(names) -> list[np.ndarray]:
    """Per region (:data:`REGIONS`), the ARKit activations it moves, as column indices.

    The mouth: ``jaw*``, ``mouth*``, ``cheekPuff``, ``tongueOut``; an eye: its ``eye*`` shapes
    (ARKit's ``Right`` is the subject's right eye, iBUG 36-41).
    """
    names = list(names)
    mouth = [j for j, n in enumerate(names)
             if n.startswith(("jaw", "mouth")) or n in ("cheekPuff", "tongueOut")]
    eyes = [[j for j, n in enumerate(names) if n.startswith("eye") and n.endswith(side)]
            for side in ("Right", "Left")]
    return [np.array(c, dtype=int) for c in (mouth, *eyes)]


def bridged(values: np.ndarray, covered: np.ndarray, unseen: np.ndarray | None = None
            ) -> np.ndarray:
    """``values`` over each run of covered frames drawn straight between the frames around it.

    Parameters
    ----------
    values : (F, k) float
    covered : (F,) bool
    unseen : (F,) bool, optional
        Frames whose values were not seen (a track's lost frames, which hold the nearest
        tracked frame's: perhaps a covered one's misreading): a covered run is bridged over
        the unseen frames beside it too, from the seen frames around them all.

    Returns
    -------
    (F, k) float64
        A run at the clip's start or end holds the one frame beside it; a clip covered
        throughout is returned as it is.
    """
    out = np.array(values, dtype=np.float64)
    F = len(out)
    cov = np.asarray(covered, dtype=bool)
    span = cov if unseen is None else cov | np.asarray(unseen, dtype=bool)
    for a, b in _runs(span):
        if (a == 0 and b == F) or not cov[a:b].any():
            continue
        left = out[a - 1] if a > 0 else out[b]
        right = out[b] if b < F else out[a - 1]
        t = (np.arange(a, b) - (a - 1)) / (b - a + 1)                     # (0, 1) inside
        out[a:b] = left + t[:, None] * (right - left)
    return out


def hold_occluded(track, occlusion: Occlusion, model):
    """The track with each covered region's activations bridged over the frames it is covered.

    Parameters
    ----------
    track : Track
        A track of an ARKit model (``blendshapes``); another is returned as it is.
    occlusion : Occlusion
        Of the track's clip (:func:`clip_occlusion`).
    model : MultilinearModel
        The track's model (the expression weights and landmarks follow the activations).

    Returns
    -------
    Track
        ``blendshapes``, the expression weights and ``landmarks2d`` changed in the covered
        frames, ``confidence`` times :data:`COVERED_CONFIDENCE` there, ``occluded`` recorded.
    """
    cov = np.asarray(occlusion.occluded, dtype=bool)
    if cov.shape != (track.n_frames, len(REGIONS)):
        raise ValueError(f"occlusion is {cov.shape}, the track has {track.n_frames} frames")
    if track.blendshapes is None or not cov.any():
        return replace(track, occluded=cov)
    old = track.blendshapes.astype(np.float64)
    new = old.copy()
    for r, cols in enumerate(region_columns(track.blendshape_names)):
        new[:, cols] = bridged(old[:, cols], cov[:, r], track.lost)
    new = np.clip(new, 0.0, 1.0)
    _, D = activation_basis(model)
    weights = dict(track.weights)
    weights["expression"] = track.weights["expression"] + (new - old) @ D   # Eq. (A), affine
    moved = _landmark_shift(track, model, weights)
    conf = np.where(cov.any(axis=1), track.confidence * COVERED_CONFIDENCE, track.confidence)
    return replace(track, blendshapes=new.astype(np.float32), weights=weights,
                   landmarks2d=track.landmarks2d + moved, confidence=conf, occluded=cov)


def _landmark_shift(track, model, weights: dict) -> np.ndarray:
    """(F, 68, 2) pixels the landmarks move by from the track's weights to ``weights``."""
    before = model.synthesize(track.weights, vertices=model.landmarks)     # (F, 68, 3)
    after = model.synthesize(weights, vertices=model.landmarks)
    d = np.einsum("fij,fnj->fni", track.rotation[:, :2], after - before)
    d = d * track.scale[:, None, None]
    d[..., 0] /= track.pixel_aspect
    d[..., 1] *= -1
    return d


def track_points(track) -> np.ndarray:
    """(F, 68, 2) the points a track's occlusion is tested at: the detector's where recorded
    (a capture track), else the fitted landmarks; NaN where the face is lost."""
    pts = track.detections2d if track.detections2d is not None else track.landmarks2d
    pts = np.array(pts, dtype=np.float64)
    pts[np.asarray(track.lost, dtype=bool)] = np.nan
    return pts


def hold_occluded_video(video, track, model):
    """:func:`hold_occluded` of a track with its clip's occlusion tested first.

    Parameters
    ----------
    video : path-like
        The tracked clip (its first ``track.n_frames`` frames are read again).
    track : Track
    model : MultilinearModel

    Returns
    -------
    Track
    """
    from ..io.video import iter_frames

    occ = clip_occlusion(iter_frames(video, stop=track.n_frames), track_points(track))
    return hold_occluded(track, occ, model)


def with_occluders(video, track, model):
    """``track --occluders``' step (``batch track --occluders`` too, on the whole clip after
    its chunks are joined): :func:`hold_occluded_video`, or the track as it is where it has
    fewer than :data:`MIN_RUN` frames (a still, or a clip no run fits in: its own frames are
    its reference, nothing could be found; ``occluded`` left None, the key's "not tested").

    Parameters
    ----------
    video : path-like
        The tracked clip.
    track : Track
    model : MultilinearModel

    Returns
    -------
    Track
    """
    if track.n_frames < MIN_RUN:
        return track
    return hold_occluded_video(video, track, model)


def covered_alpha(points: np.ndarray, covered: np.ndarray, box: tuple[int, int, int, int]
                  ) -> np.ndarray | None:
    """Where a frame's covered regions lie, as an alpha on a box of the frame: a transfer keeps
    the target's own pixels there (the occluder stays in front of the new face).

    Parameters
    ----------
    points : (68, 2) float64
        The frame's iBUG-68 points in pixels (:func:`track_points`).
    covered : (3,) bool
        The frame's row of ``Track.occluded``.
    box : (x0, y0, x1, y1) int
        The box of the frame the alpha is of.

    Returns
    -------
    (y1 - y0, x1 - x0) float32 in [0, 1] or None
        1 over each covered region's sample points' hull grown by a fifth of the eyes'
        distance, feathered by a twentieth; None where no region is covered or the points are
        unknown.
    """
    points = np.asarray(points, dtype=np.float64)
    if not np.any(covered) or not np.isfinite(points).all():
        return None
    x0, y0, x1, y1 = (int(v) for v in box)
    eyes = float(np.linalg.norm(points[42:48].mean(0) - points[36:42].mean(0)))
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    for r, pts in enumerate(region_points(points)):
        if covered[r]:
            hull = cv2.convexHull(np.round(pts - (x0, y0)).astype(np.int32))
            cv2.fillConvexPoly(mask, hull, 1)
    grow = max(1, int(round(eyes * 0.2)))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                      (2 * grow + 1, 2 * grow + 1)))
    alpha = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), max(1.0, eyes / 20.0))
    return alpha if alpha.any() else None
