"""The target frame's own pixels where the new face did not move (:mod:`facetransfer.unmoved`)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import rewrite, unmoved
from facetransfer.render import WeakPerspective, rasterize
from facetransfer.rewrite import FrameTextures, rewrite_frame
from facetransfer.rewrite_options import BlendOptions
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology

from conftest import mean_person_track

SIZE = 384


@pytest.fixture(scope="module")
def noisy(arkit_model):
    """The mean face (~250 px across) over a frame of fine detail (independent noise per pixel:
    a resampled pixel is seen at once); its per-frame texture."""
    model = arkit_model
    topo = mesh_topology(model)
    track = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=22.0)
    Vc = close_mouth(model.synthesize(track.weights_at(0)), topo)
    frame = np.random.default_rng(7).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    cam = track.camera(0)
    tex = FaceTexture(frame, frame_uvs(Vc, cam, (SIZE, SIZE)), 0)
    return topo, Vc, cam, frame, tex


def _render(noisy, shift, *, rule=True, monkeypatch=None, mouth=None):
    """The rendered face (before blending) of the target's own mesh drawn ``shift`` = (dx, dy)
    pixels off where its texture lifted it; ``rule=False``: without :mod:`facetransfer.unmoved`."""
    topo, Vc, cam, frame, tex = noisy
    moved = WeakPerspective(cam.scale, cam.rotation, cam.translation + np.asarray(shift))
    if not rule:
        monkeypatch.setattr(rewrite, "unmoved_uvs", lambda *a, **k: None)
    r = rewrite_frame(frame, Vc, moved, topo, FrameTextures(tex, mouth=mouth),
                      blending=BlendOptions("none"))
    if not rule:
        monkeypatch.undo()
    return r


def test_the_targets_own_mesh_shows_the_frame_to_the_bit(noisy, monkeypatch):
    """Drawn where it was lifted (a self-transfer) or 0.4 px off (below
    :data:`facetransfer.unmoved.D0`), every pixel of the face is the frame's own, to the bit;
    without the rule the 0.4 px resamples them (a bilinear mix of neighbours, which noise
    shows at once)."""
    frame = noisy[3]
    assert np.hypot(0.3, -0.25) < unmoved.D0
    for shift in ((0.0, 0.0), (0.3, -0.25)):
        r = _render(noisy, shift)
        m = r.face_mask
        assert m.sum() > 20000
        np.testing.assert_array_equal(r.rendered[m], frame[m])
        np.testing.assert_array_equal(r.image[m], frame[m])
    off = _render(noisy, (0.3, -0.25), rule=False, monkeypatch=monkeypatch)
    m = off.face_mask
    assert np.mean((off.rendered[m] != frame[m]).any(axis=-1)) > 0.5


def test_a_face_moved_three_pixels_keeps_nothing(noisy, monkeypatch):
    """Moved 3 px (beyond :data:`facetransfer.unmoved.D1`): the rendering is the resampled
    texture's, the same as without the rule, bit for bit; and it is not the frame's."""
    on = _render(noisy, (3.0, 0.0))
    off = _render(noisy, (3.0, 0.0), rule=False, monkeypatch=monkeypatch)
    np.testing.assert_array_equal(on.rendered, off.rendered)
    m = on.face_mask
    assert np.mean((on.rendered[m] != noisy[3][m]).any(axis=-1)) > 0.9


def test_the_soft_band_shrinks_the_displacement(noisy, monkeypatch):
    """Moved 0.8 px (between :data:`D0` and :data:`D1`): each vertex's texture position moves
    towards where it is drawn by ``w = (D1 - 0.8) / (D1 - D0)``, so each pixel is the frame's
    bilinear sample ``0.8 (1 - w)`` px off its own (a warp, not a mix of two copies), to a
    level's rounding: neither the frame's own pixel nor the old lookup's."""
    frame = noisy[3]
    shift = 0.8
    assert unmoved.D0 < shift < unmoved.D1
    on = _render(noisy, (shift, 0.0))
    off = _render(noisy, (shift, 0.0), rule=False, monkeypatch=monkeypatch)
    m = on.face_mask.copy()
    m[:, :8] = False  # where the frame's edge cuts the face, its outline rule keeps a few
    ys, xs = np.nonzero(m)
    left = shift * (1 - (unmoved.D1 - shift) / (unmoved.D1 - unmoved.D0))  # px still moved
    f = frame.astype(np.float64)
    expect = (1 - left) * f[ys, xs] + left * f[ys, xs - 1]  # sampled at x - left
    assert np.abs(on.rendered[ys, xs] - expect).max() <= 1.0
    assert np.mean((on.rendered[m] != off.rendered[m]).any(axis=-1)) > 0.5
    assert np.mean((on.rendered[m] != frame[m]).any(axis=-1)) > 0.5


def test_the_weights_and_the_texture_positions():
    """Vertices moved 0 to 2 px: the weight is 1 up to D0, 0 from D1, linear between (0 where
    the displacement is not a number); the new texture positions are ``lifted + w (drawn -
    lifted)`` (the vertices of weight 0 keep their coordinates bit for bit); nothing to change
    (None) where no vertex moved less than D1; bad input refused."""
    n = 41
    lifted = np.c_[np.linspace(10, 90, n), np.full(n, 20.0)]
    d = np.linspace(0.0, 2.0, n)
    drawn = lifted + np.c_[d * 0.6, -d * 0.8]
    w = unmoved.vertex_weights(lifted, drawn)
    np.testing.assert_allclose(w, np.clip((unmoved.D1 - d) / (unmoved.D1 - unmoved.D0), 0, 1),
                               atol=1e-12)
    bad = drawn.copy()
    bad[3] = np.nan
    assert unmoved.vertex_weights(lifted, bad)[3] == 0.0
    size = (101, 41)
    cam = _Identity()
    uvs = frame_uvs(np.c_[lifted, np.zeros(n)], cam, size)
    new = unmoved.unmoved_uvs(uvs, size, lifted, drawn)
    from facetransfer.rim import texture_positions

    np.testing.assert_allclose(texture_positions(new, size), lifted + w[:, None] * (drawn - lifted),
                               atol=1e-9)
    np.testing.assert_array_equal(new[w == 0], uvs[w == 0])
    assert unmoved.unmoved_uvs(uvs, size, lifted, lifted + [unmoved.D1, 0.0]) is None
    with pytest.raises(ValueError):
        unmoved.vertex_weights(lifted, drawn, d0=1.0, d1=0.5)
    with pytest.raises(ValueError):
        unmoved.vertex_weights(lifted, drawn[:5])
    with pytest.raises(ValueError):
        unmoved.unmoved_uvs(uvs[:5], size, lifted, drawn)


def test_the_weight_at_each_pixel_is_interpolated_from_the_corners():
    """A strip of triangles moved 0 px on the left to 2 px on the right: the per-pixel weight
    (for pictures) is 1 where the corners moved at most D0, 0 where they moved D1 or more, and
    0 off the mesh."""
    n = 21
    x = np.linspace(10, 90, n)
    P = np.concatenate([np.c_[x, np.full(n, 10.0)], np.c_[x, np.full(n, 30.0)]])
    i = np.arange(n - 1)
    faces = np.concatenate([np.c_[i, i + n, i + 1], np.c_[i + 1, i + n, i + n + 1]])
    cam = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    V = np.c_[P, np.zeros(2 * n)]
    r = rasterize(V, faces, cam, (100, 40))
    drawn = cam.project(V)
    lifted = drawn + np.c_[2.0 * (drawn[:, 0] - 10) / 80, np.zeros(2 * n)]
    wmap = unmoved.unmoved_weight(r, faces, unmoved.vertex_weights(lifted, drawn))
    row = wmap[20]
    cols = np.arange(100)
    d = 2.0 * (cols - 10) / 80
    assert (row[(cols >= 10) & (d <= unmoved.D0 - 0.1)] == 1).all()
    assert (row[(cols <= 90) & (d >= unmoved.D1 + 0.1)] == 0).all()
    mid = (d > unmoved.D0 + 0.1) & (d < unmoved.D1 - 0.1)
    np.testing.assert_allclose(row[mid], (unmoved.D1 - d[mid]) / (unmoved.D1 - unmoved.D0),
                               atol=0.02)
    assert (wmap[~r.mask] == 0).all()


class _Identity:
    """A camera that projects (x, y, z) to (x, y)."""

    @staticmethod
    def project(V):
        return np.array(V[:, :2], np.float64)


def test_the_sources_mouth_is_still_painted_over(noisy):
    """With a mouth texture (another image) the mouth's pixels are the mouth texture's, not
    the frame's the rule keeps under them."""
    topo, Vc, cam, frame, tex = noisy
    other = 255 - frame
    r = _render(noisy, (0.0, 0.0), mouth=FaceTexture(other, tex.uvs, 0))
    mm = r.mouth_mask
    assert mm.sum() > 200
    np.testing.assert_array_equal(r.rendered[mm], other[mm])


def test_a_texture_that_is_not_the_frame_is_looked_up_as_before(noisy, monkeypatch):
    """A guard: a face texture whose image is not the frame being rewritten (``texture=
    "constant"``, or another frame's: here the frame's copy, equal in every pixel) gives no
    lifted positions (:func:`facetransfer.rim.lifted_positions`), and the rule leaves its
    coordinates alone: the face 0.3 px off is resampled, bit for bit as without the rule."""
    topo, Vc, cam, frame, tex = noisy
    other = (topo, Vc, cam, frame, FaceTexture(frame.copy(), tex.uvs, 0))
    on = _render(other, (0.3, -0.25))
    off = _render(other, (0.3, -0.25), rule=False, monkeypatch=monkeypatch)
    np.testing.assert_array_equal(on.rendered, off.rendered)
    m = on.face_mask
    assert np.mean((on.rendered[m] != frame[m]).any(axis=-1)) > 0.5
