"""The fiftieth session's faster kernels (render50, track50) against the code they replaced,
kept here as references (each as it was at 67b8988), on random inputs and their edges: boxes
of one or two rows or columns, empty and full masks, masks touching the border, odd sizes,
views and Fortran order, NaN and inf where the old code took them."""

from __future__ import annotations

import cv2
import numba
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facetransfer import composite, jacobi, lip_colour, patch, rim
from facetransfer.jacobi import jacobi_sweeps
from facetransfer.render import raster
from facetransfer.track.landmarks import mapping_matrix, mediapipe_to_ibug

_SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow])


# ---- the references (67b8988's code) -------------------------------------------------------

@numba.njit
def _old_sweeps(h, inner, y0, x0, iterations, new):
    H, W = inner.shape
    hf, nf = h.reshape(h.size), new.reshape(new.size)
    for _ in range(iterations):
        for y in range(H):
            o = np.uint64(3 * W * y)
            up = np.uint64(3 * ((y0 + max(y - 1, 0)) * h.shape[1] + x0))
            row = np.uint64(3 * ((y0 + y) * h.shape[1] + x0))
            dn = np.uint64(3 * ((y0 + min(y + 1, H - 1)) * h.shape[1] + x0))
            for x in (0, W - 1):
                for c in range(3):
                    j = np.uint64(3 * x + c)
                    jl = np.uint64(3 * max(x - 1, 0) + c)
                    jr = np.uint64(3 * min(x + 1, W - 1) + c)
                    nf[o + j] = jacobi._mean4(hf[up + j], hf[row + jl], hf[row + jr],
                                              hf[dn + j])
            for i in range(3, 3 * W - 3):
                j = np.uint64(i)
                nf[o + j] = jacobi._mean4(hf[up + j], hf[row + j - np.uint64(3)],
                                          hf[row + j + np.uint64(3)], hf[dn + j])
        for y in range(H):
            for x in range(W):
                if inner[y, x]:
                    for c in range(3):
                        h[y0 + y, x0 + x, c] = new[y, x, c]


@numba.njit
def _old_window_alpha(m, x, y, oy, ox, od, r, feather, edge_outside):
    h, w = m.shape
    best = 2 * (r + 1) * (r + 1)
    for i in range(od.shape[0]):
        yy, xx = y + oy[i], x + ox[i]
        if yy < 0 or yy >= h or xx < 0 or xx >= w:
            if edge_outside:
                best = od[i]
                break
        elif m[yy, xx] == 0:
            best = od[i]
            break
    return min(np.sqrt(np.float32(best)) / np.float32(feather), np.float32(1.0))


@numba.njit
def _old_alpha_kernel(m, deep, r, feather, edge_outside, a):
    h, w = m.shape
    k = 2 * r + 1
    d2 = np.empty(k * k, np.int64)
    for i in range(k * k):
        d2[i] = (i // k - r) ** 2 + (i % k - r) ** 2
    order = np.argsort(d2, kind="mergesort")
    oy, ox, od = order // k - r, order % k - r, d2[order]
    for y in range(h):
        for x in range(w):
            if deep[y, x] or not m[y, x]:
                a[y, x] = np.float32(1.0) if deep[y, x] else np.float32(0.0)
            else:
                a[y, x] = _old_window_alpha(m, x, y, oy, ox, od, r, feather, edge_outside)


@numba.njit
def _old_coverage(xy, F, W, H, front, skip, mask):
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0 or not np.isfinite(area) or (front and area > 0):
            continue
        if raster._covered(skip, x0, y0) and raster._covered(skip, x1, y1) \
                and raster._covered(skip, x2, y2):
            continue
        xmin, xmax, ymin, ymax = raster._pixel_box(x0, y0, x1, y1, x2, y2, W, H)
        if xmin > xmax or ymin > ymax:
            continue
        pos = area > 0
        for iy in range(int(ymin), int(ymax) + 1):
            for ix in range(int(xmin), int(xmax) + 1):
                if mask[iy, ix]:
                    continue
                w0, w1, w2 = raster._edges(x0, y0, x1, y1, x2, y2, float(ix), float(iy))
                if pos:
                    inside = not ((w0 < 0) | (w1 < 0) | (w2 < 0))
                else:
                    inside = not ((w0 > 0) | (w1 > 0) | (w2 > 0))
                if inside:
                    mask[iy, ix] = 1


@numba.njit
def _old_gain_samples(pts, ox, oy, sx0, sy0, face, part, max_samples, lut, u, v, r, centre):
    n = pts.shape[0]
    dx, dy = np.int64(ox) + np.int64(sx0), np.int64(oy) + np.int64(sy0)
    sx = sy = 0
    x_lo = x_hi = pts[0, 0]
    y_lo = y_hi = pts[0, 1]
    for i in range(n):
        x, y = pts[i, 0] + dx, pts[i, 1] + dy
        sx += x
        sy += y
        x_lo, x_hi = min(x_lo, pts[i, 0]), max(x_hi, pts[i, 0])
        y_lo, y_hi = min(y_lo, pts[i, 1]), max(y_hi, pts[i, 1])
    cx, cy = float(sx) / float(n), float(sy) / float(n)
    scale = float(max(y_hi - y_lo, x_hi - x_lo, 1))
    step = max(1, -(-n // max_samples))
    j = 0
    for i in range(0, n, step):
        x, y = np.int64(pts[i, 0]) + ox, np.int64(pts[i, 1]) + oy
        u[j] = (x + sx0 - cx) / scale
        v[j] = (y + sy0 - cy) / scale
        for c in range(3):
            r[j, c] = lut[face[y, x, c]] - lut[part[y, x, c]]
        j += 1
    centre[0], centre[1], centre[2] = cx, cy, scale


def _old_recolour(image, w, target_lab, keep):
    moved = w > 0.0
    if not moved.any():
        return
    lab = cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    x = lab[moved]
    c0, c1 = lip_colour.CHROMA_RAMP
    ww = w[moved] * np.clip((np.hypot(x[:, 1], x[:, 2]) - c0) / (c1 - c0), 0.0, 1.0)
    go = ww > 0.0
    x += ww[:, None] * (1.0 - np.asarray(keep, np.float32)) * (
        np.asarray(target_lab, np.float32) - x)
    lab[moved] = x
    rgb = cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)
    moved[moved] = go
    image[moved] = np.clip(rgb[moved] * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _old_mediapipe_to_ibug(points):
    P = np.asarray(points, dtype=np.float64)
    A = mapping_matrix(P.shape[-2])
    out = np.einsum("im,...md->...id", A, np.nan_to_num(P))
    unknown = np.einsum("im,...m->...i", A != 0, np.isnan(P).any(axis=-1)) > 0
    out[unknown] = np.nan
    return out


# ---- strategies ------------------------------------------------------------------------------

def _mask(draw, h: int, w: int, rng) -> np.ndarray:
    """A random (h, w) bool mask: empty, full, sparse, dense or a blob touching the border."""
    kind = draw(st.sampled_from(["empty", "full", "sparse", "dense", "blob"]))
    if kind == "empty":
        return np.zeros((h, w), bool)
    if kind == "full":
        return np.ones((h, w), bool)
    if kind == "blob":
        yy, xx = np.mgrid[:h, :w]
        cy, cx = rng.uniform(-1, h), rng.uniform(-1, w)
        return (yy - cy) ** 2 + (xx - cx) ** 2 < rng.uniform(0.5, 1.5) * max(h, w) ** 2 / 4
    return rng.random((h, w)) < (0.15 if kind == "sparse" else 0.85)


@st.composite
def _boxes(draw, most: int = 14):
    h, w = draw(st.integers(1, most)), draw(st.integers(1, most))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    return h, w, rng, _mask(draw, h, w, rng)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint8)


# ---- the kernels against them ----------------------------------------------------------------

@_SETTINGS
@given(_boxes(), st.integers(0, 7), st.integers(0, 3), st.integers(0, 3), st.booleans())
def test_jacobi_sweeps_equal_the_old_kernel(box, iterations, top, left, special):
    """Pipelined sweeps (any count, any box, a region touching the box's edges or empty)
    against the sweeps over a scratch image, bit for bit, NaN, inf and -0 included."""
    h, w, rng, inner = box
    img = rng.normal(0, 50, (h + top + rng.integers(0, 3), w + left + rng.integers(0, 3), 3))
    img = img.astype(np.float32)
    if special:
        img.flat[rng.integers(0, img.size, 3)] = [np.nan, np.inf, -0.0]
    got, want = img.copy(), img.copy()
    jacobi_sweeps(got, inner, (top, left), iterations)
    if iterations > 0:
        _old_sweeps(want, np.ascontiguousarray(inner).view(np.uint8), top, left, iterations,
                    np.empty((h, w, 3), np.float32))
    np.testing.assert_array_equal(_bits(got), _bits(want))


@_SETTINGS
@given(_boxes(), st.floats(0.05, 7.0), st.booleans())
def test_feather_alpha_equals_the_old_search(box, feather, edge_outside):
    """The branch-free fill and the search cut at the first offset of alpha 1 against the
    search of every offset, bit for bit: masks empty, full, at the border, features of 1-2
    pixels, feathers below one pixel and wider than the box."""
    _, _, _, m = box
    got = composite.feather_alpha(m, feather, edge_outside=edge_outside)
    r = max(int(np.ceil(feather)), 1)
    m8 = np.ascontiguousarray(m).view(np.uint8)
    deep = cv2.erode(m8, np.ones((2 * r + 1,) * 2, np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0 if edge_outside else 1)
    want = np.empty(m.shape, np.float32)
    _old_alpha_kernel(m8, deep, r, float(max(feather, 1e-6)), edge_outside, want)
    np.testing.assert_array_equal(_bits(got), _bits(want))


@_SETTINGS
@given(_boxes(24), st.integers(0, 40), st.integers(0, 60), st.booleans(), st.booleans())
def test_coverage_equals_the_old_kernel(box, n_points, n_faces, front, odd):
    """The core test once a point against once a corner: points off the image, NaN, inf and
    huge; unused points; known pixels empty, full or anywhere."""
    h, w, rng, known = box
    xy = rng.uniform(-3, max(h, w) + 3, (max(n_points, 1), 2))
    if odd:
        xy[rng.random(xy.shape) < 0.08] = rng.choice([np.nan, np.inf, -np.inf, 1e300, -1e19])
    F = rng.integers(0, len(xy), (n_faces, 3))
    for k in (None, known):
        got = raster.coverage(xy, F, (w, h), front=front, known=k)
        if k is None:
            mask, skip = np.zeros((h, w), np.uint8), np.zeros((0, 0), np.uint8)
        else:
            mask = np.array(k, bool).view(np.uint8)
            skip = cv2.erode(mask, np.ones((5, 5), np.uint8), borderType=cv2.BORDER_CONSTANT,
                             borderValue=0)
        _old_coverage(np.ascontiguousarray(xy, np.float64), np.ascontiguousarray(F, np.int64),
                      w, h, front, skip, mask)
        np.testing.assert_array_equal(got, mask.view(bool))


@_SETTINGS
@given(_boxes(30), st.integers(1, 70), st.integers(0, 4), st.integers(0, 4),
       st.integers(-3, 3), st.integers(-3, 3))
def test_gain_samples_equal_the_old_listing(box, max_samples, oy, ox, sy, sx):
    """The samples, centre and extent read from the mask in two passes against those of
    ``cv2.findNonZero``'s list, bit for bit: a crop at an origin, shifted coordinates, one
    pixel, every pixel, sampling steps of 1 and more."""
    h, w, rng, m = box
    if not m.any():
        m[rng.integers(0, h), rng.integers(0, w)] = True
    face = rng.integers(0, 256, (h + oy + 2, w + ox + 1, 3), dtype=np.uint8)
    part = rng.integers(0, 256, face.shape, dtype=np.uint8)
    m8 = np.ascontiguousarray(m).view(np.uint8)
    n = int(np.count_nonzero(m))
    k = -(-n // max(1, -(-n // max_samples)))
    out = [[np.empty(k), np.empty(k), np.empty((k, 3)), np.empty(3)] for _ in range(2)]
    patch._gain_samples(m8, n, ox, oy, sx, sy, face, part, max_samples, patch._LOG1P_U8,
                        *out[0])
    _old_gain_samples(cv2.findNonZero(m8).reshape(n, 2), ox, oy, sx, sy, face, part,
                      max_samples, patch._LOG1P_U8, *out[1])
    for a, b in zip(*out):
        np.testing.assert_array_equal(_bits(a), _bits(b))


@_SETTINGS
@given(_boxes(40))
def test_median5_equals_opencvs_median(box):
    """The 5 x 5 windows' sums against ``cv2.medianBlur``, masks touching the border (the
    median's border replicated, not reflected), boxes of one or two rows or columns."""
    _, _, _, m = box
    kept = m.astype(np.uint8)
    np.testing.assert_array_equal(rim._median5(kept),
                                  (cv2.medianBlur(kept, 5) != 0).view(np.uint8))


@_SETTINGS
@given(_boxes(24), st.integers(0, 2 ** 32 - 1), st.booleans(), st.booleans(),
       st.sampled_from(["float32", "float64", "float16", "uint8", "int32"]))
def test_recolour_lips_equals_the_numpy_expressions(box, seed, crop, fortran, dtype):
    """The two recolouring kernels against the numpy expressions: a crop's view or a
    Fortran-ordered weight map, weights of 0, 1, negative, NaN, between; one-pixel boxes;
    weights of another dtype moved in numpy's precision (float64 with float64 or int32)."""
    h, w, _, moved = box
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h + 2, w + 3, 3), dtype=np.uint8)
    wt = np.where(moved, rng.choice([1.0, 0.5, 1e-7, rng.random()], (h, w)), 0.0)
    wt[rng.random((h, w)) < 0.05] = np.nan
    wt[rng.random((h, w)) < 0.05] = -0.5
    wt = wt.astype(np.float32) if dtype.startswith("float") else np.nan_to_num(wt) > 0.3
    wt = wt.astype(dtype)
    if fortran:
        wt = np.asfortranarray(wt)
    target = np.array([45.0, 30.0, 15.0]) + rng.normal(0, 12, 3)
    keep = np.clip(rng.random(3), lip_colour.KEEP_MIN, 1.0)
    box_ = (slice(1, 1 + h), slice(2, 2 + w)) if crop else (slice(0, h), slice(0, w))
    got, want = img.copy(), img.copy()
    lip_colour.recolour_lips(got[box_], wt, target, keep)
    _old_recolour(want[box_], wt, target, keep)
    np.testing.assert_array_equal(got, want)


@_SETTINGS
@given(st.integers(0, 3), st.sampled_from([468, 478]), st.integers(2, 3),
       st.sampled_from(["float32", "float64", "int32"]), st.booleans(),
       st.sampled_from(["none", "nan", "inf"]), st.integers(0, 2 ** 32 - 1))
def test_mediapipe_to_ibug_equals_the_old_mapping(frames, n, d, dtype, fortran, odd, seed):
    """The NaN-free path against the NaN bookkeeping's: any batch, 468 or 478 points, 2 or 3
    coordinates, float32, float64 or integers, C or Fortran order; with NaN or inf, the old
    path (taken) gives the same."""
    rng = np.random.default_rng(seed)
    P = (rng.normal(300, 80, (frames, n, d)) if frames else rng.normal(300, 80, (n, d)))
    if odd != "none" and P.size:
        P.flat[rng.integers(0, P.size, 4)] = np.nan if odd == "nan" else np.inf
    P = P.astype(dtype) if dtype != "int32" or odd == "none" else P
    if fortran:
        P = np.asfortranarray(P)
    with np.errstate(invalid="ignore"):
        got, want = mediapipe_to_ibug(P), _old_mediapipe_to_ibug(P)
    assert got.dtype == want.dtype and got.shape == want.shape
    np.testing.assert_array_equal(_bits(got), _bits(want))


def test_recolour_lips_moves_float64_weights_as_numpy_did():
    """Weights in float64 (any weights numpy's expressions would have moved in float64): the
    move in float64, as theirs, not in float32 after a cast (a million pixels: some are a
    level apart that way)."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (1000, 1000, 3), dtype=np.uint8)
    wt = rng.random((1000, 1000))
    target, keep = np.array([45.0, 30.0, 15.0]), np.array([0.4, 0.6, 0.8])
    got, want = img.copy(), img.copy()
    lip_colour.recolour_lips(got, wt, target, keep)
    _old_recolour(want, wt, target, keep)
    np.testing.assert_array_equal(got, want)
