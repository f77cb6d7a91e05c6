"""The triangles' layer flags of a frame's shading in one kernel (forty-sixth session,
:mod:`facetransfer.layer_flags`) against the numpy expressions ``rewrite._shade_frame`` made
them with before (``np.full``, :func:`facetransfer.eyes.eye_flags`,
:func:`facetransfer.jaw.jaw_flags`, the mouth's triangles by index and its ring by mask), on
random masks and the edges: no masks, empty and full ones, negative and repeated indices, a
mask that is a view."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from facetransfer.errors import ShapeError
from facetransfer.eyes import eye_flags
from facetransfer.jaw import jaw_flags
from facetransfer.layer_flags import _layer_flags, layer_flags

FACE, EYES, JAW, MOUTH = 1, 2, 4, 8
RIM, JAW_REGION, JAW_RING, MOUTH_RING = 16, 32, 64, 128


def _before(n, eye, jaw, mouth_faces, mouth_ring):
    """``rewrite._shade_frame``'s flags as it made them (commit ``c1ab903``)."""
    flags = np.full(n, FACE, np.uint8)
    if eye is not None:
        flags |= eye_flags(eye, shown=EYES, rim=RIM)
    if jaw is not None:
        flags |= jaw_flags(jaw, shaded=JAW, region=JAW_REGION, ring=JAW_RING)
    if mouth_faces is not None:
        flags[mouth_faces] |= MOUTH
        if mouth_ring is not None:
            flags[np.asarray(mouth_ring, bool)] |= MOUTH | MOUTH_RING
    return flags


def _now(n, eye, jaw, mouth_faces, mouth_ring):
    """The same by :func:`layer_flags`, as ``_shade_frame`` calls it now."""
    masks = []
    if eye is not None:
        masks += [(eye.select, EYES), (eye.rim, RIM)]
    if jaw is not None:
        masks += [(jaw.select, JAW | JAW_REGION), (jaw.ring, JAW | JAW_RING)]
    if mouth_faces is not None:
        masks.append((mouth_ring, MOUTH | MOUTH_RING))
    return layer_flags(n, FACE, masks, mouth_faces, MOUTH)


@pytest.mark.parametrize("seed", range(6))
def test_layer_flags_equal_the_numpy_expressions(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    masks = [rng.random(n) < p for p in rng.random(5)]
    masks[seed % 5][:] = seed % 2 == 0  # all or none
    eye = SimpleNamespace(select=masks[0], rim=None if seed == 3 else masks[1])
    jaw = SimpleNamespace(select=masks[2], ring=None if seed == 4 else masks[3])
    mouth = rng.integers(-n, n, int(rng.integers(0, 50)))  # negative and repeated ones too
    for e, j, m, r in ((eye, jaw, mouth, masks[4]), (None, jaw, mouth, None),
                       (eye, None, None, None), (None, None, None, None),
                       (eye, jaw, np.zeros(0, np.int64), masks[4])):
        want = _before(n, e, j, m, r)
        got = _now(n, e, j, m, r)
        assert got.dtype == np.uint8 and got.shape == (n,)
        np.testing.assert_array_equal(got, want)


def test_layer_flags_take_views_and_other_dtypes():
    rng = np.random.default_rng(7)
    big = rng.random((2, 800)) < 0.4
    view = big[0, ::2]  # (400,) bool, not contiguous
    sel = (rng.random(400) < 0.3).astype(np.uint8)  # a uint8 mask: as bool
    eye = SimpleNamespace(select=view, rim=sel)
    np.testing.assert_array_equal(_now(400, eye, None, None, None),
                                  _before(400, eye, None, None, None))


def test_layer_flags_kernel_equals_its_python_twin():
    rng = np.random.default_rng(3)
    n = 500
    ms = [rng.random(n) < 0.3 for _ in range(4)] + [np.zeros(0, bool)]
    idx = rng.integers(-n, n, 40)
    outs = [np.empty(n, np.uint8) for _ in range(2)]
    for kernel, out in zip((_layer_flags, _layer_flags.py_func), outs):
        args = []
        for m, b in zip(ms, (2, 16, 36, 68, 136)):
            args += [m, np.uint8(b)]
        assert kernel(out, np.uint8(1), *args, idx, np.uint8(8))
    np.testing.assert_array_equal(*outs)


def test_layer_flags_refuse_bad_masks_and_indices():
    with pytest.raises(ShapeError, match=r"\(10,\) bool"):
        layer_flags(10, 1, [(np.ones(9, bool), 2)])
    with pytest.raises(ShapeError, match="within the 10 triangles"):
        layer_flags(10, 1, [], np.array([3, 10]), 8)
    with pytest.raises(ShapeError, match="within the 10 triangles"):
        layer_flags(10, 1, [], np.array([-11]), 8)
    with pytest.raises(ShapeError, match="at most 5"):
        layer_flags(10, 1, [(None, 1)] * 6)
