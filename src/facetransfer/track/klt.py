"""Symmetric Kanade-Lucas-Tomasi terms (Vlasic et al. 2005, §5.1, Eq. (6); Birchfield 1996).

For a point seen at ``q`` in frame ``I`` and guessed at ``p0`` in frame ``J``, the motion
``d = p - p0`` of the point's window satisfies, to first order,

    Z d = e,    Z = Σ_w g gᵀ,    e = Σ_w (I(q + x) - J(p0 + x)) g(x),                 # Eq. (6)
    g(x) = (∇I(q + x) + ∇J(p0 + x)) / 2

summed over the window offsets ``x`` with Gaussian weights ``w``. ``Z`` is the 2x2 structure
tensor: a vertex on an edge constrains its motion only across the edge, one in a flat region
barely at all. The tracker never solves ``Z d = e`` point by point: it stacks the terms of about a
thousand vertices into one system for the pose and model weights (Eq. (7), (8)).

Frames are preprocessed once into a :class:`Pyramid`: per level, a float32 image with three
channels (intensity, ∂/∂x, ∂/∂y), so one bilinear ``cv2.remap`` samples all windows of all
points at once.

References
----------
Birchfield, S. Derivation of Kanade-Lucas-Tomasi tracking equation. 1996 (symmetric form).
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, Eq. (6).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ShapeError

__all__ = ["Pyramid", "build_pyramid", "window_offsets", "sample_windows", "klt_terms",
           "klt_terms_at", "solve_flow", "window_ncc", "robust_weights", "window_confidence"]


@dataclass(frozen=True)
class Pyramid:
    """Image pyramid of one frame for KLT.

    Attributes
    ----------
    levels : tuple of (H_l, W_l, 3) float32
        Level ``l`` is the frame downsampled ``2**l`` times; channels intensity (0..1 scale of
        255), x-gradient, y-gradient (per level pixel).
    """

    levels: tuple

    @property
    def n_levels(self) -> int:
        return len(self.levels)

    def size(self, level: int = 0) -> tuple[int, int]:
        H, W = self.levels[level].shape[:2]
        return W, H


def to_gray(frame: np.ndarray) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB (or ``(H, W)``) -> ``(H, W) float32`` intensity in 0..1."""
    f = np.asarray(frame)
    if f.ndim == 3 and f.shape[2] == 3:
        g = cv2.cvtColor(np.ascontiguousarray(f, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    elif f.ndim == 2:
        g = f
    else:
        raise ShapeError(f"frame must be (H, W, 3) RGB or (H, W) gray, got {f.shape}")
    return g.astype(np.float32) * np.float32(1.0 / 255.0)


def build_pyramid(frame: np.ndarray, n_levels: int = 3, *, blur: float = 0.8) -> Pyramid:
    """Intensity and gradient pyramid of a frame.

    Parameters
    ----------
    frame : (H, W, 3) uint8 RGB or (H, W) gray
    n_levels : int
        Number of levels (1 = full resolution only).
    blur : float
        Gaussian sigma (pixels) applied before the gradients on every level (0 = none).

    Returns
    -------
    Pyramid
    """
    g = to_gray(frame)
    levels = []
    for lv in range(max(int(n_levels), 1)):
        if lv:
            g = cv2.pyrDown(g)
        s = cv2.GaussianBlur(g, (0, 0), blur) if blur > 0 else g
        gx = cv2.Scharr(s, cv2.CV_32F, 1, 0, scale=1.0 / 32.0, borderType=cv2.BORDER_REPLICATE)
        gy = cv2.Scharr(s, cv2.CV_32F, 0, 1, scale=1.0 / 32.0, borderType=cv2.BORDER_REPLICATE)
        levels.append(cv2.merge([s, gx, gy]))  # (h, w, 3) float32, contiguous
    return Pyramid(tuple(levels))


def window_offsets(half: int = 4, *, sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Integer window offsets and Gaussian weights.

    Returns
    -------
    offsets : (m, 2) float32
        ``(dx, dy)`` for a ``(2 half + 1)²`` window.
    weights : (m,) float32
        Gaussian with ``sigma`` (default ``half / 1.5``), summing to 1.
    """
    r = np.arange(-half, half + 1, dtype=np.float32)
    dx, dy = np.meshgrid(r, r)
    off = np.stack([dx.ravel(), dy.ravel()], axis=1)
    sg = sigma if sigma is not None else max(half / 1.5, 0.5)
    w = np.exp(-(off ** 2).sum(1) / (2 * sg * sg)).astype(np.float32)
    return off, w / w.sum()


def level_coords(points: np.ndarray, level: int) -> np.ndarray:
    """Full-resolution pixel positions -> positions on pyramid level ``level`` (pyrDown centres)."""
    f = 0.5 ** level
    return (np.asarray(points, dtype=np.float64) + 0.5) * f - 0.5


def sample_windows(image: np.ndarray, points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Bilinear samples of a multi-channel image in windows around points.

    Parameters
    ----------
    image : (H, W, c) float32
    points : (n, 2) float
        Window centres in this image's pixels.
    offsets : (m, 2) float32

    Returns
    -------
    (n, m, c) float32
        Border pixels are replicated outside the image.
    """
    pts = np.asarray(points, dtype=np.float32)
    mx = pts[:, 0:1] + offsets[None, :, 0]
    my = pts[:, 1:2] + offsets[None, :, 1]
    out = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if out.ndim == 2:
        out = out[..., None]
    return out


def klt_terms(win_i: np.ndarray, win_j: np.ndarray, weights: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric KLT structure tensor and mismatch vector per point, Eq. (6).

    Parameters
    ----------
    win_i : (n, m, 3) float32
        Windows of frame ``I`` around ``q`` (intensity, ∂x, ∂y).
    win_j : (n, m, 3) float32
        Windows of frame ``J`` around the guess ``p0``.
    weights : (m,) float32
        Window weights.

    Returns
    -------
    Z : (n, 2, 2) float64
        ``Σ w g gᵀ`` with ``g = (∇I + ∇J) / 2``.
    e : (n, 2) float64
        ``Σ w (I - J) g``; then ``Z (p - p0) = e`` to first order.
    """
    g = 0.5 * (win_i[..., 1:] + win_j[..., 1:])           # (n, m, 2)
    diff = win_i[..., 0] - win_j[..., 0]                   # (n, m)
    gx, gy = g[..., 0], g[..., 1]
    prods = np.stack([gx * gx, gx * gy, gy * gy, gx * diff, gy * diff], axis=-1)  # (n, m, 5)
    sums = (prods.transpose(0, 2, 1) @ weights).astype(np.float64)               # (n, 5)
    Z = np.empty((sums.shape[0], 2, 2))
    Z[:, 0, 0] = sums[:, 0]
    Z[:, 0, 1] = Z[:, 1, 0] = sums[:, 1]
    Z[:, 1, 1] = sums[:, 2]
    e = sums[:, 3:5]
    return Z, e


def solve_flow(pyr_i: Pyramid, pyr_j: Pyramid, q: np.ndarray, p0: np.ndarray | None = None, *,
               half: int = 4, iterations: int = 5) -> np.ndarray:
    """Per-point symmetric KLT flow (each point on its own), coarse to fine.

    Not the tracker (which solves the model jointly); used to test Eq. (6) and as a diagnostic.

    Parameters
    ----------
    pyr_i, pyr_j : Pyramid
    q : (n, 2) float
        Points in frame ``I`` (full-resolution pixels).
    p0 : (n, 2) float, optional
        Initial guess in frame ``J`` (default ``q``).

    Returns
    -------
    (n, 2) float64
        Estimated positions in frame ``J``.
    """
    q = np.asarray(q, dtype=np.float64)
    p = q.copy() if p0 is None else np.asarray(p0, dtype=np.float64).copy()
    off, w = window_offsets(half)
    for lv in reversed(range(min(pyr_i.n_levels, pyr_j.n_levels))):
        f = 0.5 ** lv
        wi = sample_windows(pyr_i.levels[lv], level_coords(q, lv), off)
        for _ in range(iterations):
            wj = sample_windows(pyr_j.levels[lv], level_coords(p, lv), off)
            Z, e = klt_terms(wi, wj, w)
            det = Z[:, 0, 0] * Z[:, 1, 1] - Z[:, 0, 1] ** 2
            ok = det > 1e-12
            d = np.zeros_like(e)
            d[ok, 0] = (Z[ok, 1, 1] * e[ok, 0] - Z[ok, 0, 1] * e[ok, 1]) / det[ok]
            d[ok, 1] = (Z[ok, 0, 0] * e[ok, 1] - Z[ok, 0, 1] * e[ok, 0]) / det[ok]
            p += d / f
    return p


# -------------------------------------------------------------------------------- fast path
try:  # numba is a dependency; the numpy path is the reference and the fallback
    import numba as _nb
except ImportError:  # pragma: no cover
    _nb = None


def _terms_at_py(img, pts, offsets, weights, win_i, Z, e, Jint):  # pragma: no cover (numba)
    H, W = img.shape[0], img.shape[1]
    n, m = win_i.shape[0], win_i.shape[1]
    for k in range(n):
        zxx = 0.0
        zxy = 0.0
        zyy = 0.0
        ex = 0.0
        ey = 0.0
        for j in range(m):
            x = pts[k, 0] + offsets[j, 0]
            y = pts[k, 1] + offsets[j, 1]
            if x < 0.0:
                x = 0.0
            elif x > W - 1.0:
                x = W - 1.0
            if y < 0.0:
                y = 0.0
            elif y > H - 1.0:
                y = H - 1.0
            x0 = int(x)
            y0 = int(y)
            if x0 > W - 2:
                x0 = W - 2
            if y0 > H - 2:
                y0 = H - 2
            fx = x - x0
            fy = y - y0
            w00 = (1.0 - fx) * (1.0 - fy)
            w01 = fx * (1.0 - fy)
            w10 = (1.0 - fx) * fy
            w11 = fx * fy
            jv = (w00 * img[y0, x0, 0] + w01 * img[y0, x0 + 1, 0]
                  + w10 * img[y0 + 1, x0, 0] + w11 * img[y0 + 1, x0 + 1, 0])
            jx = (w00 * img[y0, x0, 1] + w01 * img[y0, x0 + 1, 1]
                  + w10 * img[y0 + 1, x0, 1] + w11 * img[y0 + 1, x0 + 1, 1])
            jy = (w00 * img[y0, x0, 2] + w01 * img[y0, x0 + 1, 2]
                  + w10 * img[y0 + 1, x0, 2] + w11 * img[y0 + 1, x0 + 1, 2])
            Jint[k, j] = jv
            gx = 0.5 * (win_i[k, j, 1] + jx)
            gy = 0.5 * (win_i[k, j, 2] + jy)
            d = win_i[k, j, 0] - jv
            ww = weights[j]
            zxx += ww * gx * gx
            zxy += ww * gx * gy
            zyy += ww * gy * gy
            ex += ww * gx * d
            ey += ww * gy * d
        Z[k, 0, 0] = zxx
        Z[k, 0, 1] = zxy
        Z[k, 1, 0] = zxy
        Z[k, 1, 1] = zyy
        e[k, 0] = ex
        e[k, 1] = ey


_terms_at_nb = _nb.njit(cache=True, fastmath=True, nogil=True)(_terms_at_py) if _nb else None


def klt_terms_at(image: np.ndarray, points: np.ndarray, win_i: np.ndarray, offsets: np.ndarray,
                 weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`klt_terms` with frame ``J`` sampled at ``points`` in one pass (numba).

    Exact bilinear interpolation (border replicated); equals
    ``klt_terms(win_i, sample_windows(image, points, offsets), weights)`` up to ``cv2.remap``'s
    1/32-pixel quantisation.

    Parameters
    ----------
    image : (H, W, 3) float32
        A pyramid level of frame ``J``.
    points : (n, 2) float
        Guesses ``p0`` in this level's pixels.
    win_i : (n, m, 3) float32
        Windows of frame ``I`` (:func:`sample_windows`).
    offsets : (m, 2) float32
    weights : (m,) float32

    Returns
    -------
    Z : (n, 2, 2) float64
    e : (n, 2) float64
    win_j : (n, m) float32
        Sampled intensities of ``J`` (for the confidence).
    """
    n, m = win_i.shape[:2]
    Z = np.empty((n, 2, 2))
    e = np.empty((n, 2))
    Jint = np.empty((n, m), np.float32)
    fn = _terms_at_nb if _terms_at_nb is not None else _terms_at_py
    fn(np.ascontiguousarray(image, dtype=np.float32), np.ascontiguousarray(points, np.float64),
       np.ascontiguousarray(offsets, np.float32), np.ascontiguousarray(weights, np.float32),
       np.ascontiguousarray(win_i, np.float32), Z, e, Jint)
    return Z, e, Jint


# ------------------------------------------------------------------------------------ windows
def _correlation_terms(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (n,) of the zero-mean normalised cross-correlation of window
    pairs (n, m), in the windows' dtype."""
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    return (a * b).sum(1), np.sqrt((a * a).sum(1) * (b * b).sum(1))


def window_ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Zero-mean normalised cross-correlation of window pairs, (n, m) x (n, m) -> (n,).

    0 where either window is flat (no texture to correlate).
    """
    num, den = _correlation_terms(a, b)
    return np.divide(num, den, out=np.zeros(a.shape[0], np.float64), where=den > 1e-10)


def robust_weights(a: np.ndarray, b: np.ndarray, level: float) -> np.ndarray:
    """Per-point weights in [0, 1] from the windows' correlation (1 above ``level + 0.3``).

    Parameters
    ----------
    a, b : (n, m)
        Intensities of each point's window in the two frames.
    level : float
        Correlation at and below which a point gets no weight (0 = every weight 1).

    Returns
    -------
    (n,) float64
    """
    if level <= 0:
        return np.ones(a.shape[0])
    return np.clip((window_ncc(a, b) - level) / 0.3, 0.0, 1.0)


def window_confidence(a: np.ndarray, b: np.ndarray) -> float:
    """Median zero-mean normalised cross-correlation of window pairs (n, m), clipped to [0, 1].

    Flat windows are left out; 0 when every window is flat.
    """
    num, den = _correlation_terms(a, b)
    ok = den > 1e-10
    if not ok.any():
        return 0.0
    return float(np.clip(np.median(num[ok] / den[ok]), 0.0, 1.0))
