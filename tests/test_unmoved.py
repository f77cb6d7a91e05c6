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
        monkeypatch.setattr(rewrite, "vertex_weights", lambda *a, **k: None)
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


def test_the_soft_band_mixes_the_two_by_the_distance(noisy, monkeypatch):
    """Moved 0.8 px (between :data:`D0` and :data:`D1`): each pixel is the resampled texture's
    mixed towards the frame's by ``(D1 - 0.8) / (D1 - D0)``, to a level's rounding."""
    frame = noisy[3]
    shift = (0.8, 0.0)
    assert unmoved.D0 < 0.8 < unmoved.D1
    on = _render(noisy, shift)
    off = _render(noisy, shift, rule=False, monkeypatch=monkeypatch)
    m = on.face_mask
    w = (unmoved.D1 - 0.8) / (unmoved.D1 - unmoved.D0)
    expect = off.rendered[m] + w * (frame[m].astype(np.float64) - off.rendered[m])
    assert np.abs(on.rendered[m] - expect).max() <= 1.0
    assert np.mean(on.rendered[m] != off.rendered[m]) > 0.5
    assert np.mean(on.rendered[m] != frame[m]) > 0.5


def test_the_weight_follows_each_pixels_displacement():
    """A strip of triangles whose vertices moved 0 px on the left and 2 px on the right,
    linearly: the weight is 1 up to the column that moved D0, 0 from the column that moved D1,
    linear between; 0 off the mesh; None when no vertex moved less than D1; and
    :func:`keep_unmoved` mixes two images by it."""
    n = 21
    x = np.linspace(10, 90, n)
    P = np.concatenate([np.c_[x, np.full(n, 10.0)], np.c_[x, np.full(n, 30.0)]])
    i = np.arange(n - 1)
    faces = np.concatenate([np.c_[i, i + n, i + 1], np.c_[i + 1, i + n, i + n + 1]])
    cam = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    V = np.c_[P, np.zeros(2 * n)]
    r = rasterize(V, faces, cam, (100, 40))
    drawn = cam.project(V)
    moved = 2.0 * (drawn[:, 0] - 10) / 80
    lifted = drawn + np.c_[moved, np.zeros(2 * n)]
    values = unmoved.vertex_weights(lifted, drawn)
    w = unmoved.unmoved_weight(r, faces, values)
    row = w[20]
    cols = np.arange(100)
    d = 2.0 * (cols - 10) / 80
    inside = (cols >= 10) & (cols <= 90)
    expect = np.clip((unmoved.D1 - d) / (unmoved.D1 - unmoved.D0), 0, 1)
    np.testing.assert_allclose(row[inside], expect[inside], atol=1e-5)
    assert (row[~inside] == 0).all() and (w[~r.mask] == 0).all()
    assert unmoved.vertex_weights(drawn + [unmoved.D1, 0.0], drawn) is None
    with pytest.raises(ValueError):
        unmoved.vertex_weights(lifted, drawn, d0=1.0, d1=0.5)
    with pytest.raises(ValueError):
        unmoved.vertex_weights(lifted, drawn[:5])
    # the mix itself, in one pass, is this map's
    rng = np.random.default_rng(3)
    face, frame = (rng.integers(0, 256, (40, 100, 3), dtype=np.uint8) for _ in range(2))
    mixed = face.copy()
    unmoved.keep_unmoved(mixed, frame, r, faces, values)
    expect = face + w[..., None] * (frame.astype(np.float64) - face)
    assert np.abs(mixed - expect).max() <= 0.5 + 1e-3
    np.testing.assert_array_equal(mixed[w >= 1], frame[w >= 1])
    np.testing.assert_array_equal(mixed[w == 0], face[w == 0])
    with pytest.raises(ValueError):
        unmoved.keep_unmoved(mixed, frame[:20], r, faces, values)


def test_the_sources_mouth_is_still_painted_over(noisy):
    """With a mouth texture (another image) the mouth's pixels are the mouth texture's, not
    the frame's the rule keeps under them."""
    topo, Vc, cam, frame, tex = noisy
    other = 255 - frame
    r = _render(noisy, (0.0, 0.0), mouth=FaceTexture(other, tex.uvs, 0))
    mm = r.mouth_mask
    assert mm.sum() > 200
    np.testing.assert_array_equal(r.rendered[mm], other[mm])
