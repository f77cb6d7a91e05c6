"""The fifty-first session's faster kernels (render51) against the code they replaced, kept
here as references (each as it was at 5a62c6d), on random inputs and their edges: boxes of a
block or two, sizes not a whole number of blocks, views, empty and full masks."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facetransfer import lips, patch

_SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow])


# ---- the references (5a62c6d's code) -------------------------------------------------------

def _old_coarse(part, face, valid):
    k = patch.SHADING_STEP
    h, w = valid.shape
    if h < k or w < k:
        return None
    size, hk, wk = (w // k, h // k), h - h % k, w - w % k
    m = cv2.resize(valid[:hk, :wk].view(np.uint8).astype(np.float32), size,
                   interpolation=cv2.INTER_AREA)
    f1 = cv2.add(cv2.resize(face[:hk, :wk], size, interpolation=cv2.INTER_AREA)
                 .astype(np.float32), 1.0)
    p1 = cv2.add(cv2.resize(part[:hk, :wk], size, interpolation=cv2.INTER_AREA), 1.0)
    return f1, p1, m


def _old_displace_lips(vertices, warp, residual, rotation, scale, ratio=1.0):
    V = np.array(vertices, dtype=np.float64, copy=True)
    r = np.asarray(residual, np.float64)
    dX = np.stack([r[:, 0], -r[:, 1]], axis=1) @ np.asarray(rotation, np.float64)[:2] \
        / float(scale)
    own = warp.vertices < warp.n_vertices
    V[warp.vertices[own]] += ratio * (warp.influence[own] @ dX)
    return V


# ---- the tests ---------------------------------------------------------------------------

@_SETTINGS
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2 ** 32 - 1),
       st.sampled_from(["random", "empty", "full"]), st.booleans(), st.booleans())
def test_coarse_equals_opencvs_area_resize(h, w, seed, fill, view, whole):
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 256, (h + 3, w + 5, 3), dtype=np.uint8)
    face = face[1:h + 1, 2:w + 2] if view else np.ascontiguousarray(face[:h, :w])
    # the part: a gained uint8 face (float32), its values whole or not, up to ~1.4 x 255
    part = (rng.integers(0, 256, (h, w, 3)) * rng.uniform(0.7, 1.4, (h, w, 3)))
    part = (np.round(part) if whole else part).astype(np.float32)
    valid = {"random": rng.random((h, w)) < rng.random(), "empty": np.zeros((h, w), bool),
             "full": np.ones((h, w), bool)}[fill]
    new, old = patch._coarse(part, face, valid), _old_coarse(part, face, valid)
    if old is None:
        assert new is None
        return
    for a, b in zip(new, old):
        assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
        assert np.array_equal(a, b)


def test_coarse_equals_opencv_at_a_face_regions_size():
    rng = np.random.default_rng(51)
    face = rng.integers(0, 256, (290, 260, 3), dtype=np.uint8)[2:287, 1:256]
    part = (rng.random((285, 255, 3)) * 357.0).astype(np.float32)
    valid = rng.random((285, 255)) < 0.6
    for a, b in zip(patch._coarse(part, face, valid), _old_coarse(part, face, valid)):
        assert np.array_equal(a, b)


@_SETTINGS
@given(st.integers(2, 30), st.integers(0, 2 ** 32 - 1), st.booleans())
def test_displace_lips_equals_the_old_selection_per_frame(n, seed, centre):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, n + 1))
    verts = rng.choice(n, size=k, replace=False).astype(np.int64)
    if centre:  # the closing fan's centre, index n, among the mouth's vertices
        verts = np.append(verts, n)
    warp = lips.LipWarp(verts, rng.normal(size=(len(verts), 20)), np.arange(20) % n, n)
    V = rng.normal(size=(n, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    for _ in range(2):  # the second frame through the warp's remembered rows
        res, ratio, s = rng.normal(size=(20, 2)), float(rng.uniform(0.5, 2)), rng.uniform(1, 9)
        assert np.array_equal(lips.displace_lips(V, warp, res, q, s, ratio),
                              _old_displace_lips(V, warp, res, q, s, ratio))
