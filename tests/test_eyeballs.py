"""The eyeballs turned to the new performance's gaze (facetransfer.eyeballs, issue 13)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer import eyeballs, eyes
from facetransfer.arkit import ARKIT_NAMES
from facetransfer.render import rasterize
from facetransfer.rewrite_clip import RenderRun, rewrite_frames
from facetransfer.rewrite_options import RewriteOptions
from facetransfer.topology import close_mouth, mesh_topology
from facetransfer.track.gaze import activation_gaze, eye_model, project_iris
from test_eyes import SIZE, _acts, _track

SCLERA, IRIS, SKIN = (235, 235, 230), (30, 40, 60), (200, 150, 120)


@pytest.fixture(scope="module")
def scene(arkit_model):
    """The mean person facing the camera, an open eye painted white with a dark iris where its
    gaze (straight ahead) puts it."""
    model = arkit_model
    topo = mesh_topology(model)
    closed, fill = eyes.close_eyes(topo, model.synthesize(model.default_weights()))
    track = _track(model, _acts(1, 0.0))
    img, V, tid, iris = painted_frame(model, closed, fill, track, 0)
    return model, topo, closed, fill, track, V, tid, iris, img


def painted_frame(model, closed, fill, track, i):
    """Frame ``i`` of ``track``: skin, its eye openings sclera, a dark iris where its gaze
    (its eyeLook* activations) puts each; with the mesh ``V``, the raster's ``tri_id`` and the
    irises' centres (2, 2)."""
    V = close_mouth(model.synthesize(track.weights_at(i)), closed)
    tid = rasterize(V, closed.faces, track.camera(i), (SIZE, SIZE)).tri_id
    hole = np.isin(tid, fill)
    g = activation_gaze(np.asarray(track.blendshapes, np.float64)[i:i + 1])
    iris = project_iris(eye_model(V[np.asarray(model.landmarks)]), g, track.rotation[i:i + 1],
                        track.scale[i:i + 1], track.translation[i:i + 1])[0]
    img = np.empty((SIZE, SIZE, 3), np.uint8)
    img[:] = SKIN
    img[hole] = SCLERA
    yy, xx = np.mgrid[:SIZE, :SIZE]
    for p in iris:
        img[hole & ((xx - p[0]) ** 2 + (yy - p[1]) ** 2 <= 4.5 ** 2)] = IRIS
    return img, V, tid, iris


def _look(eye: str, direction: str, value: float, F: int = 1) -> np.ndarray:
    a = _acts(F, 0.0)
    a[:, ARKIT_NAMES.index(f"eyeLook{direction}{eye}")] = value
    return a


def test_the_shift_is_the_irises_move_in_the_reference_frame(scene):
    model, topo, closed, fill, track, V, tid, iris, img = scene
    fill_eye = np.full(len(closed.faces), -1, np.int8)
    fill_eye[fill] = 0
    balls = eyeballs.eyeballs_of(img, track, 0, model, closed.faces, V, fill_eye)
    np.testing.assert_allclose(balls.angles, 0.0)
    np.testing.assert_array_equal(balls.shift(np.zeros((2, 2))), 0.0)
    # the left eye looking out (toward the subject's left: the image's right for a frontal
    # face), by the forward model's own numbers
    g = activation_gaze(_look("Left", "Out", 0.5))[0]
    d = balls.shift(g)
    want = project_iris(balls.eyes, g[None], track.rotation[:1], track.scale[:1],
                        track.translation[:1])[0] - iris
    np.testing.assert_allclose(d, want, atol=1e-9)
    assert d[1, 0] > 3.0 and abs(d[1, 1]) < 0.5 and np.all(d[0] == 0)
    # far beyond: at most LIMIT of the eye's width
    far = balls.shift(activation_gaze(_look("Left", "Out", 1.0))[0] * 3)
    assert np.linalg.norm(far[1]) == pytest.approx(balls.limit[1])
    assert balls.limit[1] == pytest.approx(eyeballs.LIMIT * np.linalg.norm(
        np.subtract(*track.camera(0).project(V[np.asarray(model.landmarks)[[42, 45]]]))))


def test_extend_eyeballs_continues_the_opening_under_the_lids():
    img = np.zeros((40, 60, 3), np.uint8)
    img[:] = SKIN
    opening = np.zeros((40, 60), bool)
    opening[15:25, 20:40] = True
    img[opening] = SCLERA
    img[15, 20:40] = (0, 0, 0)                    # lashes on the opening's rim
    out = eyeballs.extend_eyeballs(img, opening, grow=4)
    ring = np.zeros_like(opening)       # within 3 pixels of the opening, straight out
    ring[12:28, 20:40] = True
    ring[15:25, 17:43] = True
    ring &= ~opening
    assert np.abs(out[ring].astype(int) - SCLERA).max() == 0      # sclera under the lids
    np.testing.assert_array_equal(out[16:24, 21:39], img[16:24, 21:39])   # the core kept
    assert np.abs(out[15, 20:40].astype(int) - SCLERA).max() == 0  # the lashes' rim redone
    far = np.ones_like(opening)         # beyond grow + rim of the opening
    far[9:31, 14:46] = False
    np.testing.assert_array_equal(out[far], img[far])              # the rest untouched


def test_a_transfer_turns_the_eyes_to_the_new_gaze(scene):
    """The target looks straight ahead; the new performance looks to the subject's left and
    down: each rendered iris sits where the eyeball model puts it (a pixel or so), and without
    the new gaze (a track without blendshapes) where the target's was."""
    model, topo, closed, fill, track, V, tid, iris, img = scene
    look = _look("Left", "Out", 0.5) + _look("Right", "In", 0.5) + _look("Left", "Down", 0.3) \
        + _look("Right", "Down", 0.3)
    new = _track(model, look)
    paste, one = RewriteOptions(blend="none"), RenderRun(workers=1)
    out = next(rewrite_frames([img], track, new, model, options=paste, run=one)).image
    g = activation_gaze(look)
    want = project_iris(eye_model(V[np.asarray(model.landmarks)]), g, track.rotation[:1],
                        track.scale[:1], track.translation[:1])[0]
    Vn = close_mouth(model.synthesize(new.weights_at(0)), closed)
    new_hole = np.isin(rasterize(Vn, closed.faces, track.camera(0), (SIZE, SIZE)).tri_id, fill)
    yy, xx = np.mgrid[:SIZE, :SIZE]

    def disk(p, r):
        return (xx - p[0]) ** 2 + (yy - p[1]) ** 2 <= r ** 2

    def centre(m):
        return np.array([xx[m].mean(), yy[m].mean()])

    still = dataclasses.replace(new, blendshapes=None, blendshape_names=None)
    out0 = next(rewrite_frames([img], track, still, model, options=paste, run=one)).image
    for e in (0, 1):
        move = want[e] - iris[e]
        assert np.linalg.norm(move) > 3.0
        dark = new_hole & disk(iris[e], 12) & (out.astype(int).sum(-1) < 300)
        truth = new_hole & disk(want[e], 4.5)   # the painted iris moved, where the lids show it
        assert dark.sum() > 20 and abs(int(dark.sum()) - int(truth.sum())) < 0.3 * truth.sum()
        # within a pixel and a half (the lids that eyeLookDown lowers stretch the fill's
        # mapping, and the iris with it: so does the result without the new gaze)
        np.testing.assert_allclose(centre(dark), centre(truth), atol=1.5)
        dark0 = new_hole & disk(iris[e], 12) & (out0.astype(int).sum(-1) < 300)
        np.testing.assert_allclose(centre(dark0), centre(new_hole & disk(iris[e], 4.5)),
                                   atol=2.0)
        along = (centre(dark) - centre(dark0)) @ move / (move @ move)
        assert 0.8 < along < 1.2


def test_the_target_gaze_keeps_the_targets_own_eye_direction(scene):
    """``gaze="target"``: the eyes look where the target looks in each of its frames, not where
    the new performance does (the option reaches the rewrite from ``transfer``, ``batch
    transfer`` and ``demo``)."""
    from facetransfer.batch.jobs import rewrite_options as job_options
    from facetransfer.cli.batch import transfer_settings
    from facetransfer.cli.main import build_parser
    from facetransfer.cli.transfer import rewrite_options
    from facetransfer.errors import RewriteError
    from facetransfer.rewrite_options import RewriteOptions

    model, topo, closed, fill, track, V, tid, iris, img = scene
    new = _track(model, _look("Left", "Out", 0.6) + _look("Right", "In", 0.6))
    both = {}
    for gaze in ("performance", "target"):
        both[gaze] = next(rewrite_frames([img], track, new, model, run=RenderRun(workers=1),
                                         options=RewriteOptions(gaze=gaze, blend="none"))).image
    still = dataclasses.replace(new, blendshapes=None, blendshape_names=None)
    unturned = next(rewrite_frames([img], track, still, model, run=RenderRun(workers=1),
                                   options=RewriteOptions(blend="none"))).image
    # the target looks straight ahead in its frame (the reference frame): no turn at all
    np.testing.assert_array_equal(both["target"], unturned)
    moved = np.abs(both["performance"].astype(int) - unturned).max(axis=-1) > 100
    assert moved.sum() > 20
    with pytest.raises(RewriteError, match="gaze must be one of performance, target"):
        RewriteOptions(gaze="camera")
    p = build_parser()
    base = ["transfer", "--target", "t.mp4", "--expression-from", "s.mp4", "--out", "o.mp4"]
    assert rewrite_options(p.parse_args(base)).gaze == "performance"
    assert rewrite_options(p.parse_args(base + ["--gaze", "target"])).gaze == "target"
    batch = ["batch", "transfer", "--manifest", "pairs.csv", "--out", "d", "--gaze", "target"]
    assert job_options(transfer_settings(p.parse_args(batch))).gaze == "target"
    assert p.parse_args(["demo", "--out", "o", "--gaze", "target"]).gaze == "target"


def _shift_eyeballs_numpy(eye_img, tri_id, bary, faces, uvs, balls, shift) -> None:
    """:func:`facetransfer.eyeballs.shift_eyeballs` as numpy expressions (before its kernels,
    the forty-fifth session): the reference they must equal bit for bit."""
    import cv2

    eye = balls.lookup.take(tri_id + 1)
    flat = np.flatnonzero(eye >= 0)
    if flat.size == 0:
        return
    ys, xs = np.divmod(flat, tri_id.shape[1])
    tri = tri_id[ys, xs]
    uv = np.einsum("nk,nkc->nc", bary[ys, xs].astype(np.float64), uvs[faces[tri]])
    H, W = balls.image.shape[:2]
    d = shift[eye.ravel()[flat]]
    mx = (uv[:, 0] * (W - 1) - d[:, 0]).astype(np.float32)[None]
    my = ((1.0 - uv[:, 1]) * (H - 1) - d[:, 1]).astype(np.float32)[None]
    eye_img[ys, xs] = cv2.remap(balls.image, mx, my, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)[0]


@pytest.mark.parametrize("seed", range(5))
def test_shift_eyeballs_kernels_equal_their_numpy_expressions(seed):
    """Random rasters (a fifth background), barycentrics, uvs (float64 and float32, some a
    little past the image), fill triangles of either eye or none, shifts of up to 20 px and a
    crop of a larger raster (the region's box): the same bytes as the numpy expressions; and
    with no fill pixel, nothing changes."""
    rng = np.random.default_rng(seed)
    F, n, H, W = 400, 250, int(rng.integers(30, 90)), int(rng.integers(30, 90))
    faces = rng.integers(0, n, (F, 3))
    uvs = rng.uniform(-0.05, 1.05, (n, 2))
    if seed % 2:
        uvs = uvs.astype(np.float32)
    lookup = np.concatenate([[-1], rng.integers(-1, 2, F)]).astype(np.int8)
    image = rng.integers(0, 256, (70, 80, 3), dtype=np.uint8)
    balls = eyeballs.Eyeballs(image, None, np.zeros((2, 2)), None, np.ones(2), lookup,
                              np.zeros((2, 2)))
    tid = rng.integers(-1, F, (H + 6, W + 4)).astype(np.int32)
    tid[rng.random(tid.shape) < 0.2] = -1
    bary = rng.dirichlet(np.ones(3), tid.shape).astype(np.float32)
    shift = rng.uniform(-20, 20, (2, 2))
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    got, want = img.copy(), img.copy()
    sl = (slice(3, 3 + H), slice(2, 2 + W))
    eyeballs.shift_eyeballs(got, tid[sl], bary[sl], faces, uvs, balls, shift)
    _shift_eyeballs_numpy(want, tid[sl], bary[sl], faces, uvs, balls, shift)
    np.testing.assert_array_equal(got, want)
    assert (got != img).any()
    none = dataclasses.replace(balls, lookup=np.full(F + 1, -1, np.int8))
    eyeballs.shift_eyeballs(got, tid[sl], bary[sl], faces, uvs, none, shift)
    np.testing.assert_array_equal(got, want)


def test_the_sclera_beyond_an_iris_passes_into_what_is_continued_beside_it():
    """An eye turned into its left corner (fix52's scene: an ellipse 61 x 21 pixels, its iris
    of radius 9 at column 27): under the upper lid, the sclera filled beyond the iris met the
    iris continued above it in one step of 205 levels (eyeref53: ``make demo``'s frame 40,
    a straight cut). Now the iris side passes to the sclera over about a third of the iris's
    length; beyond the iris it is the sclera still, over the iris's middle the iris."""
    yy, xx = np.mgrid[0:60, 0:100]
    img = np.zeros((60, 100, 3), np.uint8)
    img[:] = SKIN
    opening = ((xx - 50) / 30.5) ** 2 + ((yy - 30) / 10.5) ** 2 <= 1.0
    img[opening] = SCLERA
    img[opening & (np.hypot(xx - 27, yy - 30) <= 9)] = IRIS
    row = eyeballs.extend_eyeballs(img, opening, grow=8)[20, 18:30, 0].astype(int)
    assert np.abs(row[:3] - SCLERA[0]).max() <= 3 and np.all(row[-3:] == IRIS[0]), row
    assert np.abs(np.diff(row)).max() <= 60, row          # no step: a ramp
    assert ((row > IRIS[0] + 10) & (row < SCLERA[0] - 10)).sum() >= 3, row
