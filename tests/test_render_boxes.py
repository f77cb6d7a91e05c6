"""The render's kernels on a box of a whole raster (forty-sixth session): ``shade_layers``,
``shade_texture`` and ``interpolate_vertex_values`` take the box as slices of the whole
raster (one array layout, one compiled kernel), and the closing lids' mix
(:mod:`facetransfer.eye_lids`) writes into the box of the whole eye layer. Each against what
it replaced: the shading of a cropped raster by the module as it was at commit ``c1ab903``
(read from git), and the numpy expressions of ``eyes.paint_shaded_eyes`` (``_paint_eyes``) at
that commit, on random inputs and at the edges (empty boxes, one row or column, boxes past the
raster's edge, views of larger arrays)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facetransfer.eye_lids import _lid_shares, _mix_lids, lid_shares, mix_lids
from facetransfer.render import Raster, look_at_weak_perspective, rasterize
from facetransfer.render import shading

#: The commit before the boxes.
BEFORE = "c1ab903"
_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def old_shading(tmp_path_factory):
    """``facetransfer.render.shading`` as it was at :data:`BEFORE`."""
    got = subprocess.run(["git", "-C", str(_ROOT), "show",
                          f"{BEFORE}:src/facetransfer/render/shading.py"],
                         capture_output=True, text=True)
    if got.returncode != 0:
        pytest.skip(f"commit {BEFORE} is not in this checkout's history")
    path = tmp_path_factory.mktemp("before") / "_before_shading.py"
    path.write_text(got.stdout)
    spec = importlib.util.spec_from_file_location("facetransfer.render._before_shading", path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "facetransfer.render"
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _mesh(n: int = 14):
    """A bumpy grid of ``n`` x ``n`` points and its triangles (two a cell)."""
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    P = np.stack([u, v, 0.3 * np.sin(3 * u) * np.cos(2 * v)], -1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = (i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(),
                  i[1:, 1:].ravel())
    return P, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


#: boxes (rows, columns) of a (40, 52) raster: all, inside, one row, one column, empty, past
#: the edges, negative starts
BOXES = [(slice(0, 40), slice(0, 52)), (slice(7, 31), slice(9, 44)), (slice(20, 21),
         slice(3, 50)), (slice(2, 38), slice(26, 27)), (slice(10, 10), slice(5, 30)),
         (slice(12, 30), slice(40, 40)), (slice(25, 90), slice(30, 200)),
         (slice(-15, None), slice(-20, -2))]


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(46)
    P, F = _mesh()
    # the mesh drawn partly past the raster's left and top edges
    cam = look_at_weak_perspective(P, (52, 40), fill=1.3, offset=(-9.0, -6.0))
    return rng, P, F, rasterize(P, F, cam, (52, 40))


def _crop(r: Raster, box) -> Raster:
    return Raster(r.depth[box], r.tri_id[box], r.bary[box], r.mask[box])


@pytest.mark.parametrize("box", BOXES)
def test_shading_a_box_equals_the_cropped_raster_before(old_shading, scene, box):
    rng, P, F, r = scene
    assert (r.tri_id >= 0).any() and (r.tri_id < 0).any()
    flags = rng.integers(0, 256, len(F)).astype(np.uint8)
    layers = [(rng.random((len(P), 2)), rng.integers(0, 256, (9 + k, 13, 3), dtype=np.uint8))
              for k in range(4)]
    old = old_shading.shade_layers(_crop(r, box), F, layers, flags)
    new = shading.shade_layers(r, F, layers, flags, box)
    for a, b in zip([*old[0], old[1]], [*new[0], new[1]], strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    sel = rng.random(len(F)) < 0.6
    old = old_shading.shade_texture(_crop(r, box), F, layers[1][0], layers[1][1], sel)
    new = shading.shade_texture(r, F, layers[1][0], layers[1][1], sel, box=box)
    for a, b in zip(old, new, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    values = rng.normal(size=len(P))
    a = old_shading.interpolate_vertex_values(r, F, values, box=box)
    b = shading.interpolate_vertex_values(r, F, values, box=box)
    assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_array_equal(a, b)


def test_shading_a_view_of_a_larger_raster_equals_before(old_shading, scene):
    # a raster whose arrays are views (not C-contiguous): copied, the same pixels
    rng, P, F, r = scene
    view = _crop(r, (slice(3, 35), slice(4, 50)))
    assert not view.tri_id.flags.c_contiguous
    layers = [(rng.random((len(P), 2)), rng.integers(0, 256, (11, 17, 3), dtype=np.uint8))]
    flags = np.ones(len(F), np.uint8)
    for a, b in zip(old_shading.shade_layers(view, F, layers, flags)[0],
                    shading.shade_layers(view, F, layers, flags)[0]):
        np.testing.assert_array_equal(a, b)
    values = rng.normal(size=len(P))
    box = (slice(5, 20), slice(2, 40))
    np.testing.assert_array_equal(old_shading.interpolate_vertex_values(view, F, values, box),
                                  shading.interpolate_vertex_values(view, F, values, box))


def test_a_box_compiles_no_second_kernel(scene):
    # the whole raster and a box of it: the kernels keep one compiled signature each (a
    # cropped raster's views were a second layout, loaded from numba's cache mid-clip)
    # (nor a read-only texture: a photo target's frames are one shared read-only view, and
    # its textures compiled a second signature mid-run)
    rng, P, F, r = scene
    tex = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    held = np.broadcast_to(tex[None], (2, 8, 8, 3))[1]  # read-only, as a photo's frames
    flags = np.ones(len(F), np.uint8)
    for box in (None, (slice(7, 31), slice(9, 44))):
        for texture in (tex, held):
            shading.shade_layers(r, F, [(rng.random((len(P), 2)), texture)], flags, box)
        shading.interpolate_vertex_values(r, F, rng.normal(size=len(P)), box=box)
    assert len(shading._shade_layers_kernel.signatures) == 1
    assert len(shading._interpolate_kernel.signatures) == 1


def test_a_box_with_a_step_is_refused(scene):
    _, P, F, r = scene
    with pytest.raises(shading.ShapeError, match="unit steps"):
        shading.interpolate_vertex_values(r, F, np.zeros(len(P)), box=(slice(0, 9, 2),
                                                                        slice(0, 9)))


def _old_shares(tid, side, a):
    """``eyes.paint_shaded_eyes``' shares at :data:`BEFORE` (on the cropped ``tid``)."""
    t = np.where(tid >= 0, side[np.maximum(tid, 0)], -1)
    return np.where(t >= 0, a[np.maximum(t, 0)], 0.0).astype(np.float32)


def _old_mix(w, eye_img, closed_img):
    """``eyes.paint_shaded_eyes``' mix at :data:`BEFORE`."""
    return np.rint((1 - w[..., None]) * eye_img + w[..., None] * closed_img).astype(np.uint8)


@pytest.mark.parametrize("box", BOXES)
def test_lid_kernels_equal_the_numpy_expressions(scene, box):
    rng, P, F, r = scene
    side = rng.integers(-1, 2, len(F)).astype(np.int8)
    a = np.array([rng.random(), 1.0 / 3.0])
    y0, x0, h, w = shading._box_of(box, r.tri_id.shape)
    got = lid_shares(r.tri_id, (y0, x0, h, w), side, a)
    np.testing.assert_array_equal(got, _old_shares(r.tri_id[box], side, a))
    assert got.dtype == np.float32 and got.shape == r.tri_id[box].shape
    # shares anywhere in [0, 1] and at its ends, a little past 1 (a blur's rounding)
    wt = rng.random((h, w)).astype(np.float32)
    wt.flat[::5] = 0.0
    wt.flat[1::7] = 1.0
    wt.flat[2::11] = np.float32(1.0000001)
    whole = rng.integers(0, 256, (40, 52, 3), dtype=np.uint8)
    whole[:, :, 1] = 255  # the extremes
    whole[::3, :, 2] = 0
    closed = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    want = whole.copy()
    want[y0:y0 + h, x0:x0 + w] = _old_mix(wt, whole[box], closed)
    mix_lids(wt, closed, whole, (y0, x0))
    np.testing.assert_array_equal(whole, want)


def test_lid_kernels_equal_their_python_twins(scene):
    rng, P, F, r = scene
    side = rng.integers(-1, 2, len(F)).astype(np.int8)
    a = rng.random(2)
    outs = [np.empty((20, 30), np.float32) for _ in range(2)]
    for kernel, out in zip((_lid_shares, _lid_shares.py_func), outs):
        kernel(r.tri_id, 5, 11, side, a, out)
    np.testing.assert_array_equal(*outs)
    w = rng.random((20, 30)).astype(np.float32)
    closed = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    imgs = [rng.integers(0, 256, (40, 52, 3), dtype=np.uint8)] * 2
    imgs = [imgs[0].copy(), imgs[0].copy()]
    for kernel, img in zip((_mix_lids, _mix_lids.py_func), imgs):
        kernel(w, closed, img, 5, 11)
    np.testing.assert_array_equal(*imgs)


def test_keeping_a_read_only_frames_pixels_compiles_no_second_kernel():
    # a photo target's frames are one shared read-only view: rewrite's keep-own mix of them
    # must reuse the kernel a video's writable frames compile (the same pixels either way)
    from facetransfer import rewrite

    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    held = np.broadcast_to(frame[None], (2, 40, 50, 3))[1]
    mask = np.zeros((40, 50), bool)
    mask[5:35, 8:42] = True
    where = np.zeros((40, 50), bool)
    where[12:20, 15:30] = True
    outs, compiled = [], []
    for f in (frame, held):
        img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
        out = img.copy()
        rewrite._keep_own(out, mask, f, where)
        outs.append((img, out))
        compiled.append(set(rewrite._keep_own_kernel.signatures))
    assert compiled[1] == compiled[0]   # the read-only frame: no signature of its own
    assert (outs[0][1][where] == frame[where]).all() and (outs[1][1][where] == frame[where]).all()
