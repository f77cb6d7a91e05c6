"""The render's numba kernels (forty-fifth session) at the edges the real pair never reaches,
against the code they replaced: the modules as they were at commit ``aec34b2`` (read from git,
loaded under other names), run on the same inputs, must give the same bytes or the same
exception. The edges: a face at or past the crop's edge, wholly outside it, a few pixels or
the whole frame, crops of one row or column or none, frames and masks that are views of larger
arrays, float32 coordinates, NaN in a coordinate, a gain or an alpha, empty and one-pixel
masks.

Before its fix the old code refused any ``cv2.remap`` of 32,767 points or more (a face more
than half past the crop's edge): the old modules run here with a ``cv2.remap`` that reads such
maps in pieces (:func:`_remap_in_pieces`, the same values a piece at a time), so that what the
kernels changed besides that fix is compared.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from facetransfer import composite, eyeballs, patch, rewrite, rim
from facetransfer.errors import MeshError
from facetransfer.render import Raster, WeakPerspective, rasterize
from test_rewrite_kernels import _blobs as _discs

#: The commit before the render's kernels.
BEFORE = "aec34b2"
_ROOT = Path(__file__).resolve().parent.parent
#: Names the modules at :data:`BEFORE` import from the current package under their names of
#: then (made public by the fifty-third session): ``module -> {name then: name now}``, lent
#: to the current modules while an old one loads.
_NAMES_THEN = {"composite": {"_blend_paste": "blend_paste", "_feather_alpha": "feather_alpha",
                             "_rows": "channel_rows", "_erode": "erode_mask",
                             "_extend": "extend_nearest"},
               "eyes": {"_paint_eyes": "paint_shaded_eyes"},
               "jaw": {"_paint_jaw": "paint_shaded_jaw"}}
_REMAP = cv2.remap


def _remap_in_pieces(src, mx, my, interpolation, *args, **kwargs):
    """``cv2.remap`` of a one-row map of any length: pieces of 32,000 columns (OpenCV refuses
    32,767 or more), each read as OpenCV reads it."""
    if mx.ndim == 2 and mx.shape[0] == 1 and mx.shape[1] >= 32767:
        return np.concatenate([_REMAP(src, mx[:, i:i + 32000], my[:, i:i + 32000],
                                      interpolation, *args, **kwargs)
                               for i in range(0, mx.shape[1], 32000)], axis=1)
    return _REMAP(src, mx, my, interpolation, *args, **kwargs)


@pytest.fixture(scope="module")
def before(tmp_path_factory):
    """``name -> module``: ``facetransfer.<name>`` as it was at :data:`BEFORE`, loaded as
    ``facetransfer._before_<name>`` (its relative imports the current package's)."""
    where = tmp_path_factory.mktemp("before")
    loaded = {}

    def load(name: str):
        if name not in loaded:
            got = subprocess.run(["git", "-C", str(_ROOT), "show",
                                  f"{BEFORE}:src/facetransfer/{name}.py"],
                                 capture_output=True, text=True)
            if got.returncode != 0:
                pytest.skip(f"commit {BEFORE} is not in this checkout's history")
            path = where / f"_before_{name}.py"
            path.write_text(got.stdout)
            spec = importlib.util.spec_from_file_location(f"facetransfer._before_{name}", path)
            mod = importlib.util.module_from_spec(spec)
            mod.__package__ = "facetransfer"
            sys.modules[spec.name] = mod
            _with_names_then(lambda: spec.loader.exec_module(mod))
            loaded[name] = mod
        return loaded[name]

    return load


def _with_names_then(run) -> None:
    """``run()`` with the current modules answering to their names of :data:`BEFORE` too
    (:data:`_NAMES_THEN`); those names gone again after it."""
    mods = {m: importlib.import_module(f"facetransfer.{m}") for m in _NAMES_THEN}
    try:
        for m, names in _NAMES_THEN.items():
            for then, now in names.items():
                setattr(mods[m], then, getattr(mods[m], now))
        run()
    finally:
        for m, names in _NAMES_THEN.items():
            for then in names:
                if hasattr(mods[m], then):
                    delattr(mods[m], then)


@pytest.fixture
def pieces(monkeypatch):
    """``cv2.remap`` as :func:`_remap_in_pieces` (the kernels' own reads stay below the
    limit, so it changes nothing for them)."""
    monkeypatch.setattr(cv2, "remap", _remap_in_pieces)


def _outcome(fn):
    """``fn()`` or the type and message of what it raised."""
    try:
        return fn()
    except Exception as e:  # noqa: BLE001 (compared, not swallowed)
        return (type(e), str(e))


def _same(old, new, what: str) -> None:
    """The same result (arrays: dtype, shape and bytes, NaN where NaN) or the same exception;
    ``None`` and tuples of arrays alike."""
    if isinstance(old, tuple) and old and isinstance(old[0], type):
        assert new == old, f"{what}: before raised {old}, now {new!r:.200}"
        return
    assert not (isinstance(new, tuple) and new and isinstance(new[0], type)), \
        f"{what}: now raises {new}"
    if old is None:
        assert new is None, what
        return
    for a, b in zip(*(x if isinstance(x, tuple) else (x,) for x in (old, new)), strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape, f"{what}: {a.dtype} {a.shape}, " \
            f"now {b.dtype} {b.shape}"
        np.testing.assert_array_equal(a, b, err_msg=what)


def _grid(n: int, side: float):
    """An ``n`` x ``n`` grid of points over ``side`` pixels, and its triangles (two a cell)."""
    u, v = np.meshgrid(np.linspace(0, side, n), np.linspace(0, side, n))
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = (i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(),
                  i[1:, 1:].ravel())
    return np.c_[u.ravel(), v.ravel()], np.r_[np.c_[a, b, c], np.c_[b, d, c]]


def _blobs(rng, shape, n: int) -> np.ndarray:
    """``n`` random discs (radius 2-14 px) on a ``shape`` (H, W) bool mask
    (:func:`test_rewrite_kernels._blobs`'s)."""
    return _discs(rng, shape, n, (2, 15))


def _view(a: np.ndarray) -> np.ndarray:
    """``a`` as every other column of a larger array (a strided view of the same values)."""
    big = np.zeros((a.shape[0], 2 * a.shape[1]) + a.shape[2:], a.dtype)
    big[:, ::2] = a
    return big[:, ::2]


def _shrunk_face(rng, W: int, H: int):
    """A 15 x 15 grid face 60 px across lifted at a random place around a ``W`` x ``H`` crop
    (often partly or wholly past its edges) and drawn 1-6 px further in (the rim rule's case):
    ``(raster, faces, lifted, drawn)``, or None where nothing of it falls in the crop."""
    g, faces = _grid(15, 60.0)
    unit = (g - g.mean(axis=0)) / np.maximum(
        np.linalg.norm(g - g.mean(axis=0), axis=1, keepdims=True), 1e-9)
    off = rng.uniform(-60, 60, 2)
    lifted, drawn = g + off, g - rng.uniform(1, 6) * unit + off
    pixels = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    try:
        r = rasterize(np.c_[drawn, np.zeros(len(g))], faces, pixels, (W, H))
    except MeshError:  # nothing of it in the crop
        return None
    return r, faces, lifted, drawn


def test_drawn_inside_at_the_crops_edges_equals_before(before, pieces):
    """Grid faces anywhere about crops of 1 to 69 px a side (one row, one column; the face
    past any edge or wholly outside), and each with its corners' places in float32, its raster
    a strided view, a vertex drawn or lifted at NaN, its faces Fortran-ordered: the rule keeps
    the same pixels as before (some in all: the comparison is not of empty masks)."""
    old = before("rim")
    rng = np.random.default_rng(45)
    kept = cases = 0
    for _ in range(150):
        W, H = (int(v) for v in rng.integers(1, 70, 2))
        face = _shrunk_face(rng, W, H)
        if face is None:
            continue
        r, faces, lifted, drawn = face
        nan_drawn, nan_lifted = drawn.copy(), lifted.copy()
        nan_drawn[rng.integers(len(drawn))] = np.nan
        nan_lifted[rng.integers(len(lifted))] = np.nan
        view = Raster(r.depth, _view(r.tri_id), r.bary, _view(r.mask))
        for what, args in {
                "plain": (r, faces, lifted, drawn),
                "float32": (r, faces.astype(np.int32), lifted.astype(np.float32),
                            drawn.astype(np.float32)),
                "views": (view, np.asfortranarray(faces), lifted, _view(drawn)),
                "NaN drawn": (r, faces, lifted, nan_drawn),
                "NaN lifted": (r, faces, nan_lifted, drawn)}.items():
            with np.errstate(invalid="ignore"):
                want = _outcome(lambda: old.drawn_inside(args[0].mask, *args))
                got = _outcome(lambda: rim.drawn_inside(args[0].mask, *args))
            _same(want, got, f"{what} {W}x{H}")
            kept += int(np.sum(want)) if isinstance(want, np.ndarray) else 0
            cases += 1
    assert cases > 300 and kept > 2000


def _eyes_case(rng, H: int, W: int, *, every: bool = False, bary=np.float32):
    """:func:`facetransfer.eyeballs.shift_eyeballs`' inputs on a crop ``H`` x ``W`` (a view
    of a larger raster): ``(eye_img, tri_id, bary, faces, uvs, eyeballs, shift)``; ``every``:
    each triangle a fill triangle (every covered pixel read)."""
    F, n = 400, 250
    lookup = np.concatenate([[-1], rng.integers(0 if every else -1, 2, F)]).astype(np.int8)
    balls = eyeballs.Eyeballs(rng.integers(0, 256, (70, 80, 3), np.uint8), None,
                              np.zeros((2, 2)), None, np.ones(2), lookup, np.zeros((2, 2)))
    tid = rng.integers(-1, F, (H + 6, W + 4)).astype(np.int32)
    b = rng.dirichlet(np.ones(3), tid.shape).astype(bary)
    sl = (slice(3, 3 + H), slice(2, 2 + W))
    return (rng.integers(0, 256, (H, W, 3), np.uint8), tid[sl], b[sl],
            rng.integers(0, n, (F, 3)), rng.uniform(-0.05, 1.05, (n, 2)), balls,
            rng.uniform(-20, 20, (2, 2)))


def test_shift_eyeballs_at_the_edges_equals_before(before, pieces):
    """Region boxes of one row, one column, none; a barycentric or a shift of NaN or inf;
    float64 barycentrics; the eye image a strided view; and 80,000 fill pixels (more than one
    ``cv2.remap`` reads: before, it raised): the same bytes as before."""
    old = before("eyeballs")
    rng = np.random.default_rng(13)
    cases = {"one row": _eyes_case(rng, 1, 50), "one column": _eyes_case(rng, 50, 1),
             "no rows": _eyes_case(rng, 0, 10), "no columns": _eyes_case(rng, 10, 0),
             "float64": _eyes_case(rng, 20, 30, bary=np.float64),
             "4K eye": _eyes_case(rng, 200, 400, every=True)}
    nan = _eyes_case(rng, 20, 20)
    nan[2][3, 2, 1] = np.nan
    cases["NaN barycentric"] = nan
    cases["NaN shift"] = nan[:6] + (np.array([[np.nan, 0.0], [1.0, np.inf]]),)
    cases["view"] = (_view(nan[0]),) + nan[1:]
    for what, (img, *args) in cases.items():
        want, got = img.copy(), img.copy()
        _same(_outcome(lambda: old.shift_eyeballs(want, *args)),
              _outcome(lambda: eyeballs.shift_eyeballs(got, *args)), what)
        np.testing.assert_array_equal(got, want, err_msg=what)
    huge = cases["4K eye"]
    assert np.count_nonzero(huge[1] >= 0) > 32767
    got = huge[0].copy()
    eyeballs.shift_eyeballs(got, *huge[1:])
    assert (got != huge[0]).any(axis=-1).sum() > 32767


def _keep_own_cases(rng):
    """``{what: (face_img, face_mask, frame, where)}`` of :func:`facetransfer.rewrite._keep_own`
    at the edges (kept pixels at the corners, a last row, images of one row or column, none,
    all; a face mask of none; the frame and masks strided views)."""
    def case(H, W, where, face_mask=None, frame_view=False):
        big = rng.integers(0, 256, (H, 2 * W, 3), np.uint8)
        return (rng.integers(0, 256, (H, W, 3), np.uint8),
                rng.random((H, W)) > 0.1 if face_mask is None else face_mask,
                big[:, ::2] if frame_view else big[:, :W].copy(), where)

    def at(H, W, *px):
        w = np.zeros((H, W), bool)
        for y, x in px:
            w[y, x] = True
        return w

    H, W = 30, 40
    row = np.zeros((H, W), bool)
    row[-1] = True
    return {"none": case(H, W, at(H, W)), "top left": case(H, W, at(H, W, (0, 0))),
            "bottom right": case(H, W, at(H, W, (H - 1, W - 1)), frame_view=True),
            "last row": case(H, W, row), "one-row image": case(1, W, at(1, W, (0, 3))),
            "one-column image": case(H, 1, at(H, 1, (4, 0))),
            "all": case(H, W, np.ones((H, W), bool), frame_view=True),
            "no face": case(H, W, np.ones((H, W), bool), np.zeros((H, W), bool)),
            "views": case(H, W, _view(rng.random((H, W)) > 0.7),
                          _view(rng.random((H, W)) > 0.1), frame_view=True)}


def test_keep_own_at_the_edges_equals_before(before):
    """:func:`facetransfer.rewrite._keep_own` on :func:`_keep_own_cases`, into the face image
    itself and into a view of a larger one: the same bytes as before, nothing written beyond
    the view."""
    old = before("rewrite")
    rng = np.random.default_rng(7)
    changed = 0
    for what, (img, face_mask, frame, where) in _keep_own_cases(rng).items():
        padded = np.zeros((img.shape[0] + 2, img.shape[1] + 3, 3), np.uint8)
        padded[1:-1, 2:-1] = img
        for into_view in (False, True):
            outs = []
            for fn in (old._keep_own, rewrite._keep_own):
                out = (padded if into_view else img).copy()
                fn(out[1:-1, 2:-1] if into_view else out, face_mask, frame, where)
                outs.append(out)
            np.testing.assert_array_equal(outs[1], outs[0], err_msg=what)
            changed += int((outs[0] != (padded if into_view else img)).any(axis=-1).sum())
    assert changed > 1000


def test_blend_paste_at_the_edges_equals_before(before):
    """:func:`facetransfer.composite.blend_paste` with and without ``s``, into a view of a
    larger image, on one pixel, on masks of none, an alpha of NaN or inf, float64 alphas and
    membranes, strided masks and alphas: the same bytes as before; with no rows or columns
    (before: OpenCV's merge raised) nothing is written."""
    old = before("composite")
    rng = np.random.default_rng(3)

    def case(h, w, *, m=None, a=None, s=False, view=False, f=np.float32):
        m = rng.random((h, w)) > 0.3 if m is None else m
        base = rng.integers(0, 256, (h, w, 3), np.uint8)
        mem = (rng.random((h, w, 3)) * 300 - 20).astype(f)
        a = rng.random((h, w)).astype(np.float32) if a is None else a
        src = rng.integers(0, 256, (h, w, 3), np.uint8) if s else None
        big = rng.integers(0, 256, (h + 4, w + 5, 3), np.uint8)
        outs = []
        for fn in (old._blend_paste, composite.blend_paste):
            b = big.copy()
            out = b[2:2 + h, 1:1 + w] if view else b[:h, :w].copy()
            fn(m, base, mem, a, out, s=src)
            outs.append(b if view else out)
        np.testing.assert_array_equal(outs[1], outs[0])
        return int((outs[0] != (big if view else big[:h, :w])).sum())

    changed = case(20, 30) + case(20, 30, s=True) + case(20, 30, s=True, view=True)
    changed += case(1, 1, m=np.ones((1, 1), bool)) + case(8, 8, m=np.zeros((8, 8), bool))
    for a in (np.nan, np.inf, -np.inf):
        changed += case(4, 5, a=np.full((4, 5), a, np.float32), view=True)
    changed += case(6, 7, a=rng.random((6, 7)), f=np.float64)
    changed += case(10, 12, m=_view(rng.random((10, 12)) > 0.5),
                    a=_view(rng.random((10, 12)).astype(np.float32)), s=True)
    assert changed > 1000
    for h, w in ((0, 5), (5, 0)):
        out = np.zeros((h, w, 3), np.uint8)
        composite.blend_paste(np.ones((h, w), bool), out.copy(), np.ones((h, w, 3), np.float32),
                              np.ones((h, w), np.float32), out)
        assert out.shape == (h, w, 3)


def test_feather_alpha_at_the_edges_equals_before(before):
    """:func:`facetransfer.composite.feather_alpha` of masks of one pixel, one row, one
    column, no rows, a full square, random and strided ones, both kinds of edge, feathers from
    0 to 40 and NaN and inf: the same alpha (or exception) as before."""
    old = before("composite")
    rng = np.random.default_rng(5)
    masks = [np.ones((1, 1), bool), np.ones((1, 9), bool), np.ones((9, 1), bool),
             np.zeros((0, 4), bool), np.ones((5, 5), bool), rng.random((30, 41)) > 0.2,
             _view(rng.random((30, 41)) > 0.1), _blobs(rng, (40, 50), 4)]
    some = 0.0
    for m in masks:
        for edge_outside in (True, False):
            for feather in (0.0, 1e-9, 0.5, 1.0, 2.5, 40.0, np.nan, np.inf):
                want = _outcome(lambda: old._feather_alpha(m, feather,
                                                           edge_outside=edge_outside))
                got = _outcome(lambda: composite.feather_alpha(m, feather,
                                                               edge_outside=edge_outside))
                _same(want, got, f"{m.shape} {edge_outside} {feather}")
                if isinstance(want, np.ndarray):
                    some += float(np.nansum((want > 0) & (want < 1)))
    assert some > 100


def _region(rng, kind: int, shape) -> np.ndarray:
    """A region mask of ``shape`` (H, W): discs, one corner pixel, the last row, the last
    column, none or all (``kind`` 0-5)."""
    m = _blobs(rng, shape, 3) if kind == 0 else np.zeros(shape, bool)
    if kind == 1:
        m[0, 0] = True
    elif kind == 2:
        m[-1, :] = True
    elif kind == 3:
        m[:, -1] = True
    elif kind == 5:
        m[:] = True
    return m


def test_match_outline_at_the_edges_equals_before(before):
    """:func:`facetransfer.patch.match_outline` and its region's entry with the shading and
    hue fields, grey pixels and opacity on regions of one corner pixel, the last row or
    column, none (the gain fit's error), all, and discs; a ring compared or not, rejection or
    not, the face a strided view: the same bytes (or error) as before."""
    old = before("patch")
    rng = np.random.default_rng(11)
    H, W = 60, 70
    changed = 0
    for trial in range(30):
        face = rng.integers(0, 256, (H, W, 3), np.uint8)
        part = np.clip(face * rng.uniform(0.7, 1.3, 3) + rng.normal(0, 8, face.shape),
                       0, 255).astype(np.uint8)
        mask = _region(rng, trial % 6, (H, W))
        face_mask = mask | _blobs(rng, (H, W), 4)
        opts = dict(compare=None if trial % 4 else _blobs(rng, (H, W), 5),
                    reject=None if trial % 3 else (0.2, 0.5))
        for f in (face, _view(face)):
            want = _outcome(lambda: old.match_outline(f, part, mask, face_mask, **opts))
            _same(want, _outcome(lambda: patch.match_outline(f, part, mask, face_mask, **opts)),
                  f"match_outline {trial}")
            changed += int((want != face).sum()) if isinstance(want, np.ndarray) else 0
        for shading, hue, grey, opacity in ((6.0, 0.0, None, 1.0), (0.0, 8.0, True, 0.5),
                                            (6.0, 8.0, _blobs(rng, (H, W), 2),
                                             rng.random((H, W)).astype(np.float32))):
            outs = [face.copy(), face.copy()]
            _same(*(_outcome(lambda: fn(face, part, mask, face_mask, out, feather=2.0,
                                        reject_where=None, grey_where=grey, opacity=opacity,
                                        shading=shading, hue=hue, **opts))
                    for fn, out in zip((old._match_outline_into, patch.match_outline_into),
                                       outs)), f"into {trial}")
            np.testing.assert_array_equal(outs[1], outs[0], err_msg=f"into {trial}")
    assert changed > 10000


def test_the_fields_with_nan_and_zero_parts_equal_before(before, monkeypatch):
    """:func:`facetransfer.patch._shading_field` and :func:`facetransfer.patch._hue_field`
    on boxes of 1 to 39 px a side, a NaN in the part, an all-black part, no compared pixel:
    the same field (NaN where NaN, or None) as before. (The hue field's thin neighbourhoods
    now take the region's hue, :func:`facetransfer.patch._region_hue`, where they were held
    at 1: held at 1 here, that is tested in ``test_patch_shading.py``.)"""
    old = before("patch")
    monkeypatch.setattr(patch, "_region_hue", lambda f1, p1, m: np.ones(3, np.float32))
    rng = np.random.default_rng(17)
    fields = 0
    for trial in range(30):
        h, w = (int(v) for v in rng.integers(1, 40, 2))
        part = (rng.random((h, w, 3)) * 255).astype(np.float32)
        face = rng.integers(0, 256, (h, w, 3), np.uint8)
        valid = rng.random((h, w)) > (0.5 if trial % 3 else 1.1)
        if trial % 4 == 0:
            part[0, 0, 1] = np.nan
        if trial % 5 == 0:
            part[:] = 0
        for name in ("_shading_field", "_hue_field"):
            with np.errstate(all="ignore"):
                want = _outcome(lambda: getattr(old, name)(part.copy(), face, valid, 6.0))
                got = _outcome(lambda: getattr(patch, name)(part.copy(), face, valid, 6.0))
            _same(want, got, f"{name} {trial} {h}x{w}")
            fields += isinstance(want, np.ndarray)
    assert fields > 10


_MASKS = {"one pixel": ((5, 7), (1, 1)), "corner pixel": ((0, 0), (1, 1)),
          "two pixels": ((39, 48), (1, 2)), "last row": ((39, 0), (1, 50)),
          "last column": ((0, 49), (40, 1))}


@pytest.mark.parametrize("what", [*_MASKS, "empty", "random", "strided"])
def test_gain_field_at_the_edges_equals_before(before, what):
    """:func:`facetransfer.patch.gain_field` on masks of one pixel (at the corner too), two,
    one row or column at the far edge, none (the fit's error), random, strided, over boxes of
    one pixel, none, the far corner, reaching past the image and the default: the same gains
    (or error) as before."""
    old = before("patch")
    rng = np.random.default_rng(len(what))
    face, part = (rng.integers(0, 256, (40, 50, 3), np.uint8) for _ in range(2))
    where = np.zeros((40, 50), bool)
    if what in _MASKS:
        (y, x), (h, w) = _MASKS[what]
        where[y:y + h, x:x + w] = True
    elif what == "random":
        where = rng.random((40, 50)) > 0.5
    elif what == "strided":
        where = (rng.random((80, 100)) > 0.5)[::2, ::2]
    for box in (None, (0, 0, 1, 1), (10, 10, 10, 10), (49, 39, 50, 40), (-5, -5, 60, 50)):
        _same(_outcome(lambda: old.gain_field(face, part, where, iterations=3, box=box,
                                              max_samples=500)),
              _outcome(lambda: patch.gain_field(face, part, where, iterations=3, box=box,
                                                max_samples=500)), f"{what} {box}")


def test_gain_field_of_an_inverted_box_is_empty_or_names_the_box(before):
    """A box ``(x0, y0, x1, y1)`` with ``x1 < x0``: before the kernels, an empty field of
    ``y1 - y0`` rows (no columns); with them, numpy's "negative dimensions are not allowed",
    which names no argument; now an error that names the box (the field as before would pass
    too)."""
    old = before("patch")
    rng = np.random.default_rng(0)
    face, part = (rng.integers(0, 256, (40, 50, 3), np.uint8) for _ in range(2))
    where = rng.random((40, 50)) > 0.5
    box = (20, 20, 10, 30)
    want = old.gain_field(face, part, where, iterations=3, box=box)
    assert want.shape == (10, 0, 3)
    try:
        got = patch.gain_field(face, part, where, iterations=3, box=box)
    except ValueError as e:
        assert "box" in str(e)
    else:
        _same(want, got, "inverted box")


def _as_before(monkeypatch, before) -> None:
    """The rewrite's callers of the kernels made the code before them (:data:`BEFORE`): the
    rim rule, ``_keep_own``, the eyeballs' fill, the seams' alpha and paste, the region's gain
    fit and fields."""
    from facetransfer import eyes

    rim0, rew0, eye0, comp0, patch0 = (before(n) for n in ("rim", "rewrite", "eyeballs",
                                                            "composite", "patch"))
    monkeypatch.setattr(rewrite, "drawn_inside", _unit_scale(rim0.drawn_inside))
    monkeypatch.setattr(rewrite, "_keep_own", _unit_scale(rew0._keep_own))
    monkeypatch.setattr(eyes, "shift_eyeballs", eye0.shift_eyeballs)
    for mod in (composite, patch):
        monkeypatch.setattr(mod, "feather_alpha", comp0._feather_alpha)
        monkeypatch.setattr(mod, "blend_paste", comp0._blend_paste)
    for name in ("_grey", "_gain_factors", "_shading_field", "_hue_field"):
        monkeypatch.setattr(patch, name, getattr(patch0, name))


def _unit_scale(f):
    """``f`` (the code before :mod:`facetransfer.face_scale`) called as the rewrite calls it
    now, with the face's ``scale``: these faces are smaller than ``FACE_SPAN`` (1)."""
    def at(*args, scale: float = 1.0):
        assert scale == 1.0
        return f(*args)
    return at


#: ``rewrite_frame``'s cases: ``(frame (W, H), face scale, its offset (dx, dy) in pixels)``.
_FRAMES = {"centred": ((256, 256), 12.0, (0, 0)), "half past the left": ((256, 256), 12.0,
                                                                          (-128, 0)),
           "past the right": ((256, 256), 12.0, (100, 0)), "past a corner": ((256, 256), 12.0,
                                                                           (-110, -140)),
           "bottom edge": ((256, 256), 12.0, (0, 100)), "wholly outside": ((256, 256), 12.0,
                                                                         (300, 0)),
           "a few pixels": ((256, 256), 0.4, (0, 0)), "tiny at the edge": ((256, 256), 0.4,
                                                                          (-126, 0)),
           "one row": ((256, 1), 12.0, (0, -100)), "one column": ((1, 256), 12.0, (-128, 0)),
           "grey, past the left": ((256, 256), 12.0, (-128, 0))}


def _edge_frame(model, topo, size, scale, offset, grey: bool = False):
    """A synthetic frame ``size`` (W, H) whose face (the mean person, ``scale``, moved by
    ``offset`` from a 256² frame's middle) is skin with a dark edge, on noise; its texture the
    frame's own (``grey``: its three channels equal); the new face 4 % narrower: ``(frame, V,
    camera, FrameTextures)``."""
    from conftest import mean_person_track

    from facetransfer.rewrite import FrameTextures
    from facetransfer.texture.face import FaceTexture, frame_uvs
    from facetransfer.topology import close_mouth

    W, H = size
    tr = mean_person_track(model, np.zeros((1, 52), np.float32), size=256, scale=scale)
    c = tr.camera(0)
    cam = WeakPerspective(c.scale, c.rotation,
                          c.translation + [offset[0] + (W - 256) / 2, offset[1] + (H - 256) / 2])
    Vc = close_mouth(model.synthesize(tr.weights_at(0)), topo)
    mask = rasterize(Vc, topo.faces, cam, (W, H)).mask
    frame = np.random.default_rng(0).integers(0, 8, (H, W, 3), np.uint8)
    frame += np.uint8(120)
    frame[mask] = (30, 25, 20)
    frame[composite.erode_mask(mask, 4)] = (200, 150, 120)
    if grey:  # a monochrome clip's frame (facetransfer.monochrome): three equal channels
        frame[:] = frame[..., 1:2]
    tex = FaceTexture(frame, frame_uvs(Vc, cam, (W, H)), 0)
    return frame, Vc * [1.0, 0.96, 1.0], cam, FrameTextures(tex)


def test_rewrite_frame_with_a_face_at_the_edges_equals_before(arkit_model, before, pieces,
                                                              monkeypatch):
    """:func:`facetransfer.rewrite.rewrite_frame` (no blend and the membrane's) of
    :data:`_FRAMES` (a face at and past each edge, wholly outside, of a few pixels, frames of
    one row or column, a grey frame) and of each frame as a strided view: image and matte the
    same as with the code before the kernels; faces past the edges are rewritten (before,
    they raised)."""
    from facetransfer.rewrite import rewrite_frame
    from facetransfer.rewrite_options import BlendOptions
    from facetransfer.topology import mesh_topology

    topo = mesh_topology(arkit_model)
    runs = {}
    for label in ("now", "before"):
        if label == "before":
            _as_before(monkeypatch, before)
        for what, (size, scale, offset) in _FRAMES.items():
            frame, V, cam, tex = _edge_frame(arkit_model, topo, size, scale, offset,
                                             grey=what.startswith("grey"))
            for mode in ("none", "fast"):
                for f in (frame, _view(frame)):
                    r = rewrite_frame(f, V, cam, topo, tex, blending=BlendOptions(mode),
                                      matte=True)
                    runs.setdefault((what, mode, f is frame), []).append(
                        (r.image, r.matte, (r.image != frame).any(axis=-1).sum()))
    for key, ((image, matte, changed), (want, want_matte, _)) in runs.items():
        np.testing.assert_array_equal(image, want, err_msg=str(key))
        np.testing.assert_array_equal(matte, want_matte, err_msg=str(key))
    changed = {k[0]: v[0][2] for k, v in runs.items()}
    assert changed["half past the left"] > 1000 and changed["past a corner"] > 100
    assert changed["wholly outside"] == 0 and changed["grey, past the left"] > 1000


def test_the_held_gain_and_block_masking_with_nan_equal_the_numpy_expressions():
    """The fields' kernels on NaN, inf and edge values (gains of NaN, +-inf, at the clip's
    ends; weights of NaN, exactly 0.05, its float32 neighbours; block shares of NaN, 0.5 and
    just below; no block left): the numpy expressions they replaced (the code before
    ``patch._held_gain`` and ``patch._keep_blocks``), bit for bit."""
    lo, hi = patch.SHADING_RANGE
    least = np.float32(0.05)
    g = np.array([np.nan, np.inf, -np.inf, lo, hi, np.nextafter(np.float32(hi), 2), 0.0, 1.1,
                  -0.0] * 4, np.float32).reshape(3, 4, 3)
    wt = np.array([np.nan, least, np.nextafter(least, 1), np.nextafter(least, 0), 0, 1,
                   np.inf, -np.inf, 0.3, np.nan, 0.05, 0.06], np.float32).reshape(3, 4)
    want, got = g.copy(), g.copy()
    np.copyto(want, 1.0, where=(wt <= 0.05)[..., None])
    np.clip(want, lo, hi, out=want)
    patch._held_gain(got, wt, least, np.float32(lo), np.float32(hi))
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got).any() and (got == 1).sum() > 3 and (got == np.float32(lo)).any()
    rng = np.random.default_rng(1)
    for m0 in (np.array([[np.nan, 0.5, np.nextafter(np.float32(0.5), 0)], [0, 1, np.inf]],
                        np.float32), np.zeros((2, 3), np.float32),
               np.full((2, 3), 0.4, np.float32)):
        for _ in range(4):
            ok, ok2 = (rng.integers(0, 2, m0.shape).astype(np.uint8) * 255 for _ in range(2))
            want, got = m0.copy(), m0.copy()
            want[~((ok > 0) & (ok2 > 0)) | (want < 0.5)] = 0.0
            assert patch._keep_blocks(got, ok, ok2) == bool(want.any())
            np.testing.assert_array_equal(got, want)


def test_grey_gains_of_edge_values_equal_before(before):
    """:func:`facetransfer.patch._grey` on float64 gains (what the gain fit gives) with NaN, 0,
    inf, negative and huge and tiny values, and none: the same factors as before."""
    old = before("patch")
    g = np.array([[1.1, 0.9, 1.3], [2.0, 0.5, 1.0], [np.nan, 1.0, 1.0], [0.0, 1.0, 1.0],
                  [np.inf, 1.0, 1.0], [-1.0, 1.0, 1.0], [1e300, 1e300, 1e-300],
                  [5e-324, 1.0, 1.0], [0.0, np.inf, 1.0]])
    with np.errstate(all="ignore"):
        _same(old._grey(g), patch._grey(g), "edge gains")
        _same(old._grey(g[:0]), patch._grey(g[:0]), "no rows")
        _same(old._grey(g[::2]), patch._grey(g[::2]), "strided rows")
