"""Compositing a rendered face back into footage (§6, Fig. 7D): the membrane blend (the default),
Poisson image editing and colour matching.

Vlasic et al. (2005), §6 and Fig. 7D: "For best visual results, we blend [Pérez et al. 2003] the
face texture from the target video; the mouth texture from the source video; and the background
texture, which includes the eyes peeking through the holes in the transferred geometry."

This module solves the discrete Poisson equation of Pérez et al. (2003), Eq. (7)::

    for every pixel p in the region Ω:
        |N_p| f_p - Σ_{q ∈ N_p ∩ Ω} f_q = Σ_{q ∈ N_p ∩ ∂Ω} f*_q + Σ_{q ∈ N_p} v_pq

with ``N_p`` the 4-neighbours of ``p`` that lie inside the image (so a region touching the image
border gets a natural Neumann condition there), ``f*`` the target image (Dirichlet boundary) and
``v_pq`` the guidance field: a blend of the finite differences of one or several source images and
of the target (for feathered masks), or the larger of the source and target differences (mixed
gradients, Pérez et al. Eq. (12)–(13)).

OpenCV's ``seamlessClone`` is used where it serves (one hard-edged region, one source, away from
the image border); the sparse solver here does everything else. The rewrite's ``blend="poisson"``
is :func:`composite_face`; its default, ``blend="fast"``, is :func:`membrane_blend`: the same
equation with the source's own gradients as guidance, whose correction (harmonic, equal to
``target - source`` on the region's outline) is interpolated from the outline
(:mod:`facetransfer.jacobi`'s sweeps) instead of solved for.

References
----------
P. Pérez, M. Gangnet, A. Blake. Poisson image editing. ACM TOG 22(3), 313–318, 2003.
doi:10.1145/882262.882269
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence

import cv2
import numpy as np
import scipy.ndimage as ndi

from .errors import ShapeError, FaceTransferError
from .jacobi import jacobi_sweeps
from .jit import maybe_njit as _maybe_njit

log = logging.getLogger(__name__)

__all__ = [
    "CompositeError", "poisson_blend", "opencv_serves", "poisson_blend_multi", "feather_mask",
    "match_color", "composite_face", "composite_alpha", "membrane_blend", "membrane_alpha",
    "membrane_crop", "mask_box", "over", "MEMBRANE_MARGIN",
    # the rewrite's and the region pastes' (facetransfer.patch) pieces
    "extend_nearest", "erode_mask", "feather_alpha", "blend_paste", "channel_rows",
]

_METHODS = ("auto", "opencv", "solver")


class CompositeError(FaceTransferError):
    """Bad input to the compositing functions (shapes, dtypes, empty masks, unknown options)."""


# ---------------------------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------------------------

def _check_image(img, name: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ShapeError(f"{name} must be an (H, W, 3) image, got shape {a.shape}")
    if shape is not None and a.shape[:2] != tuple(shape):
        raise ShapeError(f"{name} has shape {a.shape}, expected ({shape[0]}, {shape[1]}, 3) "
                         "like the target")
    if a.dtype != np.uint8:
        if not np.issubdtype(a.dtype, np.number):
            raise CompositeError(f"{name} must be numeric, got dtype {a.dtype}")
        if not np.all(np.isfinite(a)):
            raise CompositeError(f"{name} has NaN or infinite values")
    return a


def _check_mask(mask, name: str, shape: tuple[int, int]) -> np.ndarray:
    """Return the mask as float64 weights in [0, 1] (bool masks become 0/1)."""
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise ShapeError(f"{name} must be (H, W) = {tuple(shape)}, got shape {m.shape}")
    if m.dtype == bool:
        return m.astype(np.float64)
    if not np.issubdtype(m.dtype, np.number):
        raise CompositeError(f"{name} must be bool or numeric in [0, 1], got dtype {m.dtype}")
    m = m.astype(np.float64)
    if not np.all(np.isfinite(m)):
        raise CompositeError(f"{name} has NaN or infinite values")
    if m.min() < 0 or m.max() > 1:
        raise CompositeError(f"{name} values must lie in [0, 1], got range "
                             f"[{m.min():.3g}, {m.max():.3g}]")
    return m


def _rounded(img: np.ndarray, dtype=np.uint8) -> np.ndarray:
    """``img`` rounded and clipped to ``dtype``'s range (uint8, or uint16 for a 16-bit target)."""
    return np.clip(np.rint(img), 0, np.iinfo(dtype).max).astype(dtype)


# ---------------------------------------------------------------------------------------------
# the sparse solver
# ---------------------------------------------------------------------------------------------

def _edge_guidance(sources, alphas, valids, target, axis: int, mixed: bool) -> np.ndarray:
    """Guidance ``v_pq`` on the edges between pixel p and its successor q along ``axis``.

    Every source k owns the edge with weight ``max(alpha_k(p), alpha_k(q))`` if both ends are
    valid pixels of that source (0 otherwise); the weights are normalised to sum at most 1 and
    the target gets the rest (feathered edges then blend the source and target gradients
    smoothly). Returns ``f_p - f_q`` differences, ``(h', w', 3)``.
    """
    def diff(img):
        return img[:-1] - img[1:] if axis == 0 else img[:, :-1] - img[:, 1:]

    def emax(a):
        return np.maximum(a[:-1], a[1:]) if axis == 0 else np.maximum(a[:, :-1], a[:, 1:])

    def eboth(v):
        return (v[:-1] & v[1:]) if axis == 0 else (v[:, :-1] & v[:, 1:])

    w = [emax(a) * (1.0 if v is None else eboth(v)) for a, v in zip(alphas, valids)]
    total = np.sum(w, axis=0)
    scale = np.where(total > 1.0, 1.0 / np.maximum(total, 1e-300), 1.0)
    d_t = diff(target)
    v = np.zeros_like(d_t)
    w_src = np.zeros(d_t.shape[:2])
    for s, wk in zip(sources, w):
        wk = wk * scale
        d_s = diff(s)
        if mixed:  # Pérez et al. Eq. (13): keep the stronger of the source and target gradients
            d_s = np.where(np.abs(d_s) > np.abs(d_t), d_s, d_t)
        v += wk[..., None] * d_s
        w_src += wk
    v += (1.0 - w_src)[..., None] * d_t
    return v


def _solve_poisson(target: np.ndarray, sources: Sequence[np.ndarray], alphas: Sequence[np.ndarray],
                   valids: Sequence[np.ndarray | None], region: np.ndarray, mixed: bool) -> np.ndarray:
    """Solve Pérez et al. Eq. (7) inside ``region`` (bool, (h, w)) of a crop; float64 (h, w, 3)."""
    import scipy.sparse as sp  # here: the default (membrane) blend never needs the solver
    import scipy.sparse.linalg as sla

    h, w = region.shape
    n = int(region.sum())
    idx = -np.ones((h, w), dtype=np.int64)
    idx[region] = np.arange(n)
    f = target.copy()
    rhs = np.zeros((n, 3))
    diag = np.zeros(n)
    rows, cols = [], []

    for axis in (0, 1):
        v = _edge_guidance(sources, alphas, valids, target, axis, mixed)  # v_pq = f_p - f_q
        if axis == 0:
            ip, iq = idx[:-1], idx[1:]
            tp, tq = target[:-1], target[1:]
        else:
            ip, iq = idx[:, :-1], idx[:, 1:]
            tp, tq = target[:, :-1], target[:, 1:]
        # every in-image edge (p, q) with at least one end in Ω contributes to both ends' rows.
        for a_idx, b_idx, b_val, sign in ((ip, iq, tq, 1.0), (iq, ip, tp, -1.0)):
            sel = a_idx >= 0
            a = a_idx[sel]
            b = b_idx[sel]
            inside = b >= 0
            # Dirichlet: a neighbour outside Ω contributes the known target value f*_q.
            contrib = sign * v[sel] + np.where(inside[:, None], 0.0, b_val[sel])
            diag += np.bincount(a, minlength=n)
            for ch in range(3):
                rhs[:, ch] += np.bincount(a, weights=contrib[:, ch], minlength=n)
            rows.append(a[inside])
            cols.append(b[inside])

    # Components of Ω with no Dirichlet neighbour (e.g. the whole image) are defined up to a
    # constant: tie them weakly to the target so that the system is non-singular.
    labels, _ = ndi.label(region)
    four = ndi.generate_binary_structure(2, 1)
    # erosion with border_value=1 keeps pixels whose in-image neighbours are all in Ω
    edge_px = region & ~ndi.binary_erosion(region, structure=four, border_value=1)
    anchored = np.zeros(labels.max() + 1, bool)
    anchored[np.unique(labels[edge_px])] = True
    floating = ~anchored[labels[region]]
    eps = 1e-6
    if floating.any():
        diag[floating] += eps
        rhs[floating] += eps * target[region][floating]

    r = np.concatenate(rows)
    c = np.concatenate(cols)
    A = sp.csc_matrix((np.concatenate([diag, -np.ones(r.size)]),
                       (np.concatenate([np.arange(n), r]), np.concatenate([np.arange(n), c]))),
                      shape=(n, n))
    lu = sla.splu(A, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    f[region] = lu.solve(rhs)
    return f


def _bbox(region: np.ndarray, pad: int = 1) -> tuple[slice, slice]:
    ys, xs = np.nonzero(region)
    h, w = region.shape
    return (slice(max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)),
            slice(max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)))


def poisson_blend_multi(target, sources: Sequence[tuple[np.ndarray, np.ndarray]], *,
                        mixed: bool = False) -> np.ndarray:
    """Poisson-blend several sources into one target, each over its own (possibly soft) mask.

    Pixels where any source has weight > 0 are solved for; every other pixel is copied from the
    target exactly. The guidance field on an edge comes from the source(s) owning it, weighted by
    their mask values, and from the target for the rest (so a feathered mask fades the source
    gradients into the target's).

    Parameters
    ----------
    target : (H, W, 3) uint8, uint16 or float
        Image to paste into (its values on the region's outline are the Dirichlet boundary);
        the sources on its scale (0-65535 for uint16).
    sources : sequence of (source (H, W, 3), mask (H, W) bool or float in [0, 1][, valid (H, W) bool])
        Source images aligned with the target (pixel (x, y) of a source lands on (x, y)).
        Where masks overlap, later sources share the edge with earlier ones in proportion.
        The optional ``valid`` marks the pixels where the source has content (e.g. a rendered
        face without its background): an edge with an invalid end takes the target's
        difference instead (default: every pixel valid, as in Pérez et al.).
    mixed : bool, keyword-only
        Mixed gradients (Pérez et al. 2003, Eq. (13)): per edge, the larger of the source and
        target differences, so that target texture shows through flat source areas.

    Returns
    -------
    (H, W, 3) uint8, or uint16 for a uint16 target

    References
    ----------
    Pérez, Gangnet, Blake (2003), Eq. (7) (discrete Poisson equation), Eq. (11)–(13).
    Vlasic et al. (2005), §6 and Fig. 7D (face from one video, mouth from another).
    """
    t = _check_image(target, "target")
    H, W = t.shape[:2]
    if len(sources) == 0:
        raise CompositeError("poisson_blend_multi needs at least one (source, mask) pair")
    srcs, alphas, valids = [], [], []
    for k, pair in enumerate(sources):
        if len(pair) not in (2, 3):
            raise CompositeError(f"sources[{k}] must be a (source, mask) pair or a "
                                 "(source, mask, valid) triple")
        srcs.append(_check_image(pair[0], f"sources[{k}] image", (H, W)).astype(np.float64))
        alphas.append(_check_mask(pair[1], f"sources[{k}] mask", (H, W)))
        valid = None
        if len(pair) == 3 and pair[2] is not None:
            valid = np.asarray(pair[2])
            if valid.shape != (H, W) or valid.dtype != bool:
                raise ShapeError(f"sources[{k}] valid must be (H, W) = {(H, W)} bool, got "
                                 f"{valid.shape} {valid.dtype}")
        valids.append(valid)
    region = np.any([a > 0 for a in alphas], axis=0)
    out = t.astype(np.float64)
    depth = np.uint16 if t.dtype == np.uint16 else np.uint8
    if not region.any():
        log.info("poisson_blend_multi: empty masks; returning the target")
        return _rounded(out, depth)
    ys, xs = _bbox(region)
    f = _solve_poisson(out[ys, xs], [s[ys, xs] for s in srcs], [a[ys, xs] for a in alphas],
                       [None if v is None else v[ys, xs] for v in valids], region[ys, xs], mixed)
    out[ys, xs] = f
    res = _rounded(out, depth)
    if t.dtype == depth:
        res[~region] = t[~region]  # exact copy outside the region
    return res


def opencv_serves(mask: np.ndarray) -> bool:
    """Whether OpenCV's seamlessClone can take ``mask`` ``(H, W)`` (bool, or 0/1): one
    hard-edged connected region that keeps 2 pixels off the image border."""
    if not np.all((mask == 0) | (mask == 1)):
        return False
    m = mask > 0
    H, W = m.shape
    if m[:2].any() or m[-2:].any() or m[:, :2].any() or m[:, -2:].any():
        return False
    _, n = ndi.label(m)
    return n == 1


def poisson_blend(source, target, mask, *, method: str = "auto", mixed: bool = False) -> np.ndarray:
    """Paste ``source`` into ``target`` over ``mask`` by Poisson image editing.

    Parameters
    ----------
    source : (H, W, 3) uint8
        Source image, aligned with the target (no offset), on the target's scale.
    target : (H, W, 3) uint8, or uint16 (16-bit values kept: the solver's)
    mask : (H, W) bool, or float in [0, 1] for a feathered edge
    method : {"auto", "opencv", "solver"}, keyword-only
        ``"opencv"``: ``cv2.seamlessClone`` (one hard-edged connected region, at least two pixels
        from the border; raises otherwise). ``"solver"``: the sparse solver of this module, which
        takes several regions, border-touching regions and feathered masks. ``"auto"`` picks
        OpenCV where it serves and the solver otherwise.
    mixed : bool, keyword-only
        Mixed gradients (Pérez et al. 2003, Eq. (13); OpenCV ``MIXED_CLONE``).

    Returns
    -------
    (H, W, 3) uint8 (uint16 for a uint16 target)
        Outside the mask equal to ``target`` exactly (solver); OpenCV may change pixels within a
        few pixels of the mask outline, since it solves over the mask's bounding box.

    References
    ----------
    Pérez, Gangnet, Blake (2003), Eq. (7) and (11)–(13).
    """
    if method not in _METHODS:
        raise CompositeError(f"method must be one of {_METHODS}, got {method!r}")
    t = _check_image(target, "target")
    s = _check_image(source, "source", t.shape[:2])
    m = _check_mask(mask, "mask", t.shape[:2])
    deep = t.dtype == np.uint16          # seamlessClone takes 8 bits
    if not (m > 0).any():
        return _rounded(t.astype(np.float64), np.uint16 if deep else np.uint8)
    use_cv = method == "opencv" or (method == "auto" and opencv_serves(m) and not deep)
    if use_cv:
        if deep or not opencv_serves(m):
            raise CompositeError("method='opencv' needs an 8-bit target and one hard-edged "
                                 "(bool) connected mask region at least 2 pixels from the "
                                 "image border; use method='solver'")
        return _seamless_clone(_rounded(s.astype(np.float64)), _rounded(t.astype(np.float64)),
                               m > 0, mixed)
    return poisson_blend_multi(t, [(s, m)], mixed=mixed)


def _seamless_clone(src: np.ndarray, dst: np.ndarray, mask: np.ndarray, mixed: bool) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    # seamlessClone crops the source to the mask's bounding box and centres that box on
    # `center` in the destination: the centre of a box of width w starting at x0 is x0 + w // 2.
    center = (int(x0 + (x1 - x0 + 1) // 2), int(y0 + (y1 - y0 + 1) // 2))
    m8 = mask.astype(np.uint8) * 255
    flag = cv2.MIXED_CLONE if mixed else cv2.NORMAL_CLONE
    return cv2.seamlessClone(src, dst, m8, center, flag)


# ---------------------------------------------------------------------------------------------
# masks and colour
# ---------------------------------------------------------------------------------------------

def feather_mask(mask, radius: float) -> np.ndarray:
    """Soft-edged version of a hard mask, extending ``radius`` pixels beyond it.

    ``alpha = smoothstep(0.5 + d / (2 radius))`` with ``d`` the signed distance to the mask's
    outline (positive inside): 1 deeper than ``radius`` inside, 0 farther than ``radius`` outside,
    0.5 on the outline.

    Parameters
    ----------
    mask : (H, W) bool
    radius : float
        Half-width of the transition in pixels; 0 returns the mask as 0/1 floats.

    Returns
    -------
    (H, W) float32 in [0, 1]
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.dtype != bool:
        raise ShapeError(f"mask must be an (H, W) bool array, got shape {m.shape} dtype {m.dtype}")
    if not np.isfinite(radius) or radius < 0:
        raise CompositeError(f"feather radius must be a finite number >= 0, got {radius}")
    if radius == 0 or not m.any() or m.all():
        return m.astype(np.float32)
    d_in = ndi.distance_transform_edt(m)     # distance to nearest outside pixel (inside)
    d_out = ndi.distance_transform_edt(~m)   # distance to nearest inside pixel (outside)
    d = np.where(m, d_in - 0.5, -(d_out - 0.5))
    x = np.clip(0.5 + d / (2.0 * radius), 0.0, 1.0)
    return (x * x * (3.0 - 2.0 * x)).astype(np.float32)


def _rgb_to_lab(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.clip(img, 0, 255).astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)


def _lab_to_rgb(lab: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(lab.astype(np.float32), cv2.COLOR_LAB2RGB) * 255.0


def match_color(source, target, source_mask, target_mask=None) -> np.ndarray:
    """Shift and scale the colours of ``source`` so its masked region matches ``target``'s.

    Per channel of CIE Lab: ``l' = (l - mean_s) * std_t / std_s + mean_t`` (Reinhard et al. 2001),
    with the statistics of ``source`` over ``source_mask`` and of ``target`` over ``target_mask``
    (default: the same mask). Applied to every source pixel.

    Parameters
    ----------
    source, target : (H, W, 3) uint8 RGB (may differ in size)
    source_mask : (H, W) bool, same size as ``source``
    target_mask : (H', W') bool, same size as ``target``, optional

    Returns
    -------
    (H, W, 3) uint8

    References
    ----------
    E. Reinhard et al. Color transfer between images. IEEE CG&A 21(5), 2001.
    """
    s = _check_image(source, "source")
    t = _check_image(target, "target")
    ms = _check_mask(source_mask, "source_mask", s.shape[:2]) > 0
    mt = ms if target_mask is None else _check_mask(target_mask, "target_mask", t.shape[:2]) > 0
    if target_mask is None and t.shape[:2] != s.shape[:2]:
        raise ShapeError(f"target {t.shape} differs from source {s.shape}: pass target_mask")
    if ms.sum() < 2 or mt.sum() < 2:
        raise CompositeError("colour matching needs at least 2 pixels in each mask")
    ls, lt = _rgb_to_lab(s), _rgb_to_lab(t)
    mu_s, sd_s = ls[ms].mean(0), ls[ms].std(0)
    mu_t, sd_t = lt[mt].mean(0), lt[mt].std(0)
    gain = np.where(sd_s > 1e-6, sd_t / np.maximum(sd_s, 1e-6), 1.0)
    out = (ls - mu_s) * gain + mu_t
    return _rounded(_lab_to_rgb(out))


def composite_face(target_frame, rendered_face, face_mask, *, mouth_source=None, mouth_mask=None,
                   color_match: bool = True, feather: float = 3.0, mixed: bool = False) -> np.ndarray:
    """Blend a rendered face into a frame by solving the Poisson equation (Vlasic et al. 2005,
    §6, Fig. 7D; the rewrite's ``blend="poisson"``, where :func:`membrane_blend` is its default).

    The face region's guidance field comes from ``rendered_face`` (optionally colour-matched to
    the target's face region first), the mouth region's from ``mouth_source`` (e.g. the source
    video's mouth), and everything outside the feathered face mask is the target frame, exactly:
    holes in ``face_mask`` (eyes, mouth opening) keep the target's own pixels.

    Parameters
    ----------
    target_frame : (H, W, 3) uint8
    rendered_face : (H, W, 3) uint8
        The face rendered in the target frame's camera; its pixels outside ``face_mask`` are
        ignored (edges leaving the face take the target's gradient).
    face_mask : (H, W) bool
        Pixels covered by the rendered face.
    mouth_source : (H, W, 3) uint8, optional
        Image whose gradients fill ``mouth_mask`` (aligned with the target).
    mouth_mask : (H, W) bool, optional
        Required with ``mouth_source``; it overrides the face inside it.
    color_match : bool
        Match the rendered face's Lab mean and deviation to the target under ``face_mask``.
    feather : float
        Soft-edge radius in pixels (:func:`feather_mask`); the region grows by this much.
    mixed : bool
        Mixed gradients.

    Returns
    -------
    (H, W, 3) uint8
        Equal to ``target_frame`` outside the dilated (feathered) masks.
    """
    t = _check_image(target_frame, "target_frame")
    if t.dtype != np.uint8:
        raise CompositeError(f"target_frame must be uint8, got {t.dtype}")
    r = _check_image(rendered_face, "rendered_face", t.shape[:2])
    fm = np.asarray(face_mask)
    if fm.shape != t.shape[:2] or fm.dtype != bool:
        raise ShapeError(f"face_mask must be (H, W) = {t.shape[:2]} bool, got {fm.shape} {fm.dtype}")
    if (mouth_source is None) != (mouth_mask is None):
        raise CompositeError("mouth_source and mouth_mask go together: pass both or neither")
    if not fm.any():
        log.warning("composite_face: empty face mask; returning the target frame")
        return t.copy()
    face = _rounded(np.asarray(r, dtype=np.float64))
    if color_match:
        face = match_color(face, t, fm)
    # The rendered image has no face beyond face_mask (background there): edges leaving the
    # face take the target's gradient (valid = face_mask), so no seam of background leaks in.
    pairs = []
    if mouth_source is not None:
        ms_img = _check_image(mouth_source, "mouth_source", t.shape[:2])
        mm = np.asarray(mouth_mask)
        if mm.shape != t.shape[:2] or mm.dtype != bool:
            raise ShapeError(f"mouth_mask must be (H, W) = {t.shape[:2]} bool, got {mm.shape} {mm.dtype}")
        a_face, a_mouth = _face_alphas(fm, mm, feather)
        pairs = [(face, a_face, fm), (ms_img, a_mouth)]
    else:
        pairs = [(face, _face_alphas(fm, None, feather)[0], fm)]
    return poisson_blend_multi(t, pairs, mixed=mixed)


def _face_alphas(fm: np.ndarray, mm: np.ndarray | None, feather: float):
    """The feathered masks of :func:`composite_face`: ``(face, mouth)`` (H, W) float32, the
    face's less where the mouth's is (mouth None without ``mm``)."""
    if mm is None:
        return feather_mask(fm, feather), None
    a_mouth = feather_mask(mm, feather)
    return feather_mask(fm & ~mm, feather) * (1.0 - a_mouth), a_mouth


def composite_alpha(face_mask, *, mouth_mask=None, feather: float = 3.0) -> np.ndarray:
    """How much of each pixel :func:`composite_face` takes from its sources: the sum of its
    feathered masks (:func:`feather_mask`: the face's, less where the mouth's is, and the
    mouth's), in [0, 1]. Where it is 0 the result is the target frame's pixel exactly; where
    it is above 0 the pixel is solved for (Pérez et al. 2003, Eq. (7)) and may differ.

    Parameters
    ----------
    face_mask : (H, W) bool
    mouth_mask : (H, W) bool, optional
        As given to :func:`composite_face` with a mouth source.
    feather : float
        As given to :func:`composite_face`.

    Returns
    -------
    (H, W) float32
    """
    fm = np.asarray(face_mask)
    if fm.ndim != 2 or fm.dtype != bool:
        raise ShapeError(f"face_mask must be an (H, W) bool array, got {fm.shape} {fm.dtype}")
    if not fm.any():   # composite_face returns the target frame
        return np.zeros(fm.shape, np.float32)
    a_face, a_mouth = _face_alphas(fm, None if mouth_mask is None else
                                   np.asarray(mouth_mask, bool), feather)
    return a_face if a_mouth is None else (a_face + a_mouth).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# the fast blend: a membrane correction (an approximation of Poisson blending)
# ---------------------------------------------------------------------------------------------

def extend_nearest(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``img`` inside ``mask``, its nearest inside pixel outside (no step across the outline)."""
    if mask.all() or not mask.any():
        return img.copy()
    _, (iy, ix) = ndi.distance_transform_edt(~mask, return_indices=True)
    return img[iy, ix]


#: 4-connected structuring element (``scipy.ndimage``'s default for binary morphology)
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


def erode_mask(mask: np.ndarray, iterations: int) -> np.ndarray:
    """Binary erosion by the 4-connected cross, pixels beyond the image counting as outside
    (equal to ``scipy.ndimage.binary_erosion(mask, iterations=iterations)``)."""
    m8 = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)  # 0/1 bytes, no copy
    return cv2.erode(m8, _CROSS, iterations=int(iterations), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0).view(bool)


#: Pixels around the region's bounding box in :func:`membrane_blend`'s working crop.
MEMBRANE_MARGIN = 8


def over(base: np.ndarray, top: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``top`` (H, W, 3) where ``mask`` (H, W) bool, ``base`` (H, W, 3) elsewhere: a new array
    (``np.where(mask[..., None], top, base)``, in one masked copy)."""
    out = np.array(base, copy=True, order="C")
    cv2.copyTo(np.ascontiguousarray(top), np.ascontiguousarray(mask).view(np.uint8), out)
    return out


def mask_box(mask: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """``(rows, columns)`` slices of the bounding box of the nonzero pixels of ``mask`` (H, W)
    bool or uint8, grown by ``margin`` and clipped to the image; None when there are none."""
    m = mask.view(np.uint8) if mask.dtype == bool else mask
    bx, by, bw, bh = cv2.boundingRect(np.ascontiguousarray(m))
    if bw <= 0 or bh <= 0:
        return None
    H, W = mask.shape
    return (slice(max(by - margin, 0), min(by + bh + margin, H)),
            slice(max(bx - margin, 0), min(bx + bw + margin, W)))


def membrane_crop(mask: np.ndarray, margin: int = MEMBRANE_MARGIN
                  ) -> tuple[slice, slice] | None:
    """The working crop of :func:`membrane_blend` over ``mask`` (H, W) bool
    (:func:`mask_box`), or None when the mask is empty. Outside it the blend reads nothing and
    writes nothing."""
    return mask_box(mask, margin)


def membrane_blend(target: np.ndarray, source: np.ndarray, mask: np.ndarray, *,
                   feather: float = 2.0, margin: int = MEMBRANE_MARGIN,
                   smooth_iterations: int = 4, outlier: float | None = 40.0) -> np.ndarray:
    """Seamless paste by a membrane correction (an approximation of Poisson blending).

    Poisson image editing with the source's own gradients as guidance (Pérez et al. 2003,
    Eq. (7)–(10)) gives ``f = source + h`` inside the mask, with ``h`` harmonic and equal to
    ``target − source`` on the outline. Here the outline is the region's own border (its pixels
    with a neighbour outside), so the source is only read inside the mask; ``h`` is interpolated
    into the region from the outline by pyramid push-pull (smooth, linear time) and a few
    Jacobi sweeps of Laplace's equation, instead of solving the sparse system; the seam is then
    feathered over ``feather`` pixels inside the mask. Outside the mask the result is ``target``
    exactly.

    Parameters
    ----------
    target, source : (H, W, 3) uint8
        ``source`` is read inside ``mask`` only.
    mask : (H, W) bool
    feather : float
        Width in pixels of the inside band where the result fades to the target.
    margin : int
        Pixels around the mask's bounding box in the working crop.
    smooth_iterations : int
        Jacobi sweeps of Laplace's equation applied to the push-pull membrane. The push-pull
        result is smooth already: on the demo pair's face, 10 sweeps instead of 4 change the
        blended pixels by at most 4 levels (PSNR 65 dB) at 2.5 times the sweeps' cost
        (``BENCHMARKS.md``, issue 13).
    outlier : float or None
        Outline pixels whose target-source difference exceeds this (0..255 scale, any channel)
        do not constrain the membrane (None: all do).

    Returns
    -------
    (H, W, 3) uint8
    """
    T = np.asarray(target)
    out = T.copy()
    mask = np.asarray(mask, bool)
    box = membrane_crop(mask, margin)
    if box is None:
        return out
    m = np.ascontiguousarray(mask[box])
    t = np.ascontiguousarray(T[box])
    s = np.ascontiguousarray(np.asarray(source)[box])
    h = _membrane(m, t, s, outlier, int(smooth_iterations))
    a = _seam_alpha(m, feather)
    crop = out[box]
    blend_paste(m, t, h, a, crop, s=s)  # in place: the region's pixels of ``out``
    return out


def _seam_alpha(m: np.ndarray, feather: float) -> np.ndarray:
    """The seam's fade of :func:`membrane_blend` over its crop's region ``m`` (h, w) bool:
    the distance to the nearest pixel outside the region over ``feather`` (the crop's margin
    is outside; pixels beyond the image are not), (h, w) float32, 0 outside ``m``."""
    return feather_alpha(m, feather, edge_outside=False) if feather > 0 else \
        m.astype(np.float32)


def membrane_alpha(mask: np.ndarray, *, feather: float = 2.0,
                   margin: int = MEMBRANE_MARGIN) -> np.ndarray:
    """How much of each pixel :func:`membrane_blend` (with the same ``mask``, ``feather`` and
    ``margin``) takes from its source and membrane: its result is ``rint(target + alpha
    (source + h - target))`` inside ``mask``, ``target`` exactly where ``alpha`` is 0 (outside
    ``mask``). Inside ``mask`` it is at least ``1 / feather`` (1 without feathering).

    Parameters
    ----------
    mask : (H, W) bool
    feather : float
    margin : int

    Returns
    -------
    (H, W) float32 in [0, 1]
    """
    mask = np.asarray(mask, bool)
    out = np.zeros(mask.shape, np.float32)
    box = membrane_crop(mask, margin)
    if box is not None:
        out[box] = _seam_alpha(np.ascontiguousarray(mask[box]), feather)
    return out


def feather_alpha(m: np.ndarray, feather: float, *, edge_outside: bool) -> np.ndarray:
    """``clip(d / feather, 0, 1)`` with ``d`` the Euclidean distance of each pixel of ``m``
    (h, w) bool to the nearest pixel outside it (0 outside): (h, w) float32.

    Equal to ``cv2.distanceTransform(..., DIST_L2, DIST_MASK_PRECISE)`` scaled and clipped, but
    computed only where it is below 1: pixels whose ``(2r + 1)²`` window (``r = ceil(feather)``)
    lies inside ``m`` are farther than ``feather`` from outside (a square erosion finds them,
    1 there, 0 elsewhere); the rest of ``m`` (its band along the outline) search their
    window, nearest offsets first, up to the first whose alpha is 1 (:func:`_alpha_kernel`).
    ``edge_outside``: pixels beyond the crop count as outside (else, as OpenCV, they do not).
    """
    r = max(int(np.ceil(feather)), 1)
    m8 = m.view(np.uint8)
    deep = cv2.erode(m8, _square(2 * r + 1), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0 if edge_outside else 1)
    a = np.empty(m.shape, np.float32)
    # deep lies in m (each window holds its own pixel): 1 there, 0 outside m, searched between
    _alpha_kernel(m8, deep, r, float(max(feather, 1e-6)), bool(edge_outside), a)
    return a


@functools.lru_cache(maxsize=None)
def _square(k: int) -> np.ndarray:
    """The ``k`` x ``k`` square structuring element (uint8 ones), made once per size."""
    return np.ones((k, k), np.uint8)


def _alpha_kernel_py(m, deep, r, feather, edge_outside, a):  # pragma: no cover (numba)
    """:func:`feather_alpha` into ``a`` (h, w) float32 from ``m`` (h, w) uint8 and its square
    erosion ``deep``: 1 in ``deep``, 0 outside ``m`` (a row without a branch: vectorised),
    then the window search at the row's band pixels (in ``m``, not ``deep``), up to the first
    offset whose alpha is 1 (those after it are no nearer: 1, as when none is outside)."""
    h, w = m.shape
    k = 2 * r + 1
    d2 = np.empty(k * k, np.int64)
    for i in range(k * k):
        d2[i] = (i // k - r) ** 2 + (i % k - r) ** 2
    order = np.argsort(d2, kind="mergesort")
    oy, ox, od = order // k - r, order % k - r, d2[order]
    n = od.shape[0]  # the offsets searched: those of an alpha below 1
    for i in range(od.shape[0]):
        if min(np.sqrt(np.float32(od[i])) / np.float32(feather), np.float32(1.0)) >= 1:
            n = i
            break
    for y in range(h):
        for x in range(w):
            a[y, x] = np.float32(1.0) if deep[y, x] else np.float32(0.0)
        for x in range(w):
            if m[y, x] and not deep[y, x]:
                a[y, x] = _window_alpha(m, x, y, oy, ox, od, n, feather, edge_outside)


def _window_alpha_py(m, x, y, oy, ox, od, n, feather, edge_outside):  # pragma: no cover
    """:func:`_alpha_kernel`'s search at ``(x, y)``: the first of the ``n`` nearest offsets
    ``(ox, oy)`` outside, its squared distance ``od`` as ``min(sqrt / feather, 1)`` in
    float32; 1 if none is (numba, inlined)."""
    h, w = m.shape
    for i in range(n):
        yy, xx = y + oy[i], x + ox[i]
        if yy < 0 or yy >= h or xx < 0 or xx >= w:
            if edge_outside:
                return min(np.sqrt(np.float32(od[i])) / np.float32(feather), np.float32(1.0))
        elif m[yy, xx] == 0:
            return min(np.sqrt(np.float32(od[i])) / np.float32(feather), np.float32(1.0))
    return np.float32(1.0)


_window_alpha = _maybe_njit(_window_alpha_py, inline=True)


def _blend_value_py(b, ay, f):  # pragma: no cover (numba, inlined)
    """``rint(b + ay (f - b))`` clipped to 0..255 as uint8, in float32 (``b`` a uint8 value)."""
    bf = np.float32(b)
    v = np.rint(bf + ay * (f - bf))
    return np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))


_blend_value = _maybe_njit(_blend_value_py, inline=True)


def blend_paste(m: np.ndarray, base: np.ndarray, f: np.ndarray, a: np.ndarray,
                out: np.ndarray, *, s: np.ndarray | None = None) -> None:
    """``out = rint(base + a (f - base))`` clipped to 0..255 at the pixels of ``m`` (h, w) bool
    (``base``, ``out`` (h, w, 3) uint8, ``f`` (h, w, 3) and ``a`` (h, w) float32), in float32;
    ``out`` (a view of a larger image, in place) is left alone elsewhere. With ``s`` (h, w, 3)
    uint8: ``f + s`` in float32 (as ``f += s`` would) in place of ``f``. The paste of
    :func:`membrane_blend` (``f`` = membrane, ``s`` = source, ``base`` = target) and of
    :func:`facetransfer.patch.match_outline`.

    The kernels run over rows of per-channel values, a row of ``m`` and ``a`` repeated per
    channel into scratch rows first: without a branch per pixel they are vectorised (4x faster
    than per pixel)."""
    w = m.shape[1]
    args = (m.view(np.uint8), np.ascontiguousarray(a, np.float32), np.empty(3 * w, np.uint8),
            np.empty(3 * w, np.float32))
    if s is None:
        _blend_rows(channel_rows(base), channel_rows(f), channel_rows(out), *args)
    else:
        _blend_rows_sum(*map(channel_rows, (base, f, s, out)), *args)


def channel_rows(x: np.ndarray) -> np.ndarray:
    """``x`` (h, w, 3), rows of contiguous pixels (a crop of an image), seen as ``(h, 3 w)``
    without a copy (numpy refuses, AttributeError, where that needs one: a write to a copy
    would be lost)."""
    v = x.view()
    v.shape = (x.shape[0], x.shape[1] * x.shape[2])
    return v


def _spread_py(m, a, y, m3, a3):  # pragma: no cover (numba, inlined)
    """Row ``y`` of ``m`` (h, w) uint8 and ``a`` (h, w) float32 repeated per channel into
    ``m3``, ``a3`` (3 w,)."""
    for x in range(m.shape[1]):
        for c in range(3):
            m3[3 * x + c] = m[y, x]
            a3[3 * x + c] = a[y, x]


_spread = _maybe_njit(_spread_py, inline=True)


def _blend_rows_py(base, f, out, m, a, m3, a3):  # pragma: no cover (numba)
    """:func:`blend_paste` on rows ``(h, 3 w)`` of channel values: ``out = _blend_value(base,
    a, f)`` where ``m``, else ``out`` as it is (``m3``, ``a3``: a row's scratch)."""
    H, L = out.shape
    for y in range(H):
        _spread(m, a, y, m3, a3)
        for j in range(L):
            v = _blend_value(base[y, j], a3[j], f[y, j])
            out[y, j] = v if m3[j] else out[y, j]


def _blend_rows_sum_py(base, h, s, out, m, a, m3, a3):  # pragma: no cover (numba)
    """:func:`_blend_rows` with ``f = h + s`` (``s`` uint8, added in float32)."""
    H, L = out.shape
    for y in range(H):
        _spread(m, a, y, m3, a3)
        for j in range(L):
            v = _blend_value(base[y, j], a3[j], h[y, j] + np.float32(s[y, j]))
            out[y, j] = v if m3[j] else out[y, j]


def _ring_differences_py(ry, rx, t, s, dr):  # pragma: no cover (numba)
    """``dr = t - s`` (float32) at the pixels ``(ry, rx)``; returns the largest absolute
    channel difference of each pixel, ``(k,)`` float32."""
    big = np.empty(ry.shape[0], np.float32)
    for i in range(ry.shape[0]):
        y, x = ry[i], rx[i]
        mx = np.float32(0.0)
        for c in range(3):
            d = np.float32(t[y, x, c]) - np.float32(s[y, x, c])
            dr[i, c] = d
            mx = max(mx, abs(d))
        big[i] = mx
    return big


_alpha_kernel = _maybe_njit(_alpha_kernel_py)
_blend_rows = _maybe_njit(_blend_rows_py)
_blend_rows_sum = _maybe_njit(_blend_rows_sum_py)
_ring_differences = _maybe_njit(_ring_differences_py)


def _outline(m: np.ndarray, t: np.ndarray, s: np.ndarray, outlier: float | None):
    """The outline of region ``m`` (h, w) bool and ``target - source`` on it.

    The outline is the region's pixels with one of their 8 neighbours outside (the crop's edge
    counts as outside); outline pixels where ``t`` and ``s`` (h, w, 3) differ by ``outlier`` or
    more in a channel are left out (unless that leaves fewer than a quarter).

    Returns
    -------
    ring, interior : (h, w) bool
    ry, rx : (k,) int
        The outline pixels kept.
    dr : (k, 3) float32
        ``t - s`` there.
    """
    interior = cv2.erode(m.view(np.uint8), np.ones((3, 3), np.uint8),
                         borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)
    ring = m & ~interior
    ry, rx = _nonzero(ring)
    dr = np.empty((ry.size, 3), np.float32)
    big = _ring_differences(ry, rx, t, s, dr)       # target - source on the outline
    if outlier is not None:
        # outline pixels where target and source disagree wildly (the silhouette moved with
        # the new expression, or hair crosses it) would bleed into the face: leave them out
        ok = big < float(outlier)
        if ok.sum() >= 0.25 * ok.size and not ok.all():
            ring[ry[~ok], rx[~ok]] = False
            interior = m & ~ring
            ry, rx, dr = ry[ok], rx[ok], dr[ok]
    return ring, interior, ry, rx, dr


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero`` of an (h, w) bool mask (rows, columns; row-major order), by
    ``cv2.findNonZero``."""
    pts = cv2.findNonZero(np.ascontiguousarray(mask).view(np.uint8))  # (n, [1,] 2): (x, y)
    if pts is None:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    pts = pts.reshape(-1, 2).astype(np.intp)
    return pts[:, 1], pts[:, 0]


def _membrane(m: np.ndarray, t: np.ndarray, s: np.ndarray, outlier: float | None,
              smooth_iterations: int) -> np.ndarray:
    """The membrane ``h`` (h, w, 3) float32 of :func:`membrane_blend`: ``t - s`` on the outline
    of ``m`` (:func:`_outline`), interpolated inside by push-pull
    (:func:`facetransfer.texture.fill_holes`, from the outline's pixels:
    :func:`facetransfer.texture.merge.push_pull_points`) and ``smooth_iterations`` Jacobi
    sweeps of Laplace's equation."""
    from .texture.merge import push_pull_points

    ring, interior, ry, rx, dr = _outline(m, t, s, outlier)
    # (h, w, 3): the membrane, = target - source on the outline (fill_holes of the outline)
    h = push_pull_points(m.shape, ry, rx, dr)
    # Jacobi sweeps of Laplace's equation (the mean of the 4 neighbours; all in one kernel)
    # smooth the push-pull result towards harmonic; the outline keeps its values
    h = np.ascontiguousarray(h, dtype=np.float32)
    # the sweeps work on the interior's box grown by the pixel its neighbours reach (the same
    # values as over the whole crop: an interior pixel's 4 neighbours lie in the region)
    box = mask_box(interior, 1)
    if box is None or smooth_iterations <= 0:
        return h
    jacobi_sweeps(h, interior[box], (box[0].start, box[1].start), int(smooth_iterations))
    return h
