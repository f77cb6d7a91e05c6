"""The rendered face's outer band where its outline moved inside the target's
(:mod:`facetransfer.rim`)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import rim
from facetransfer.render import rasterize
from facetransfer.rewrite import rewrite_frame
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology

from conftest import mean_person_track

SIZE = 512
SKIN, EDGE, BACK = (200, 150, 120), (30, 25, 20), (120, 160, 120)


def test_outward_shift_is_how_much_farther_out_the_texture_lies():
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    P = 50.0 + 10.0 * np.stack([np.cos(t), np.sin(t)], axis=1)
    np.testing.assert_allclose(rim.outward_shift(P, 50.0 + 1.2 * (P - 50.0)), 2.0, atol=1e-5)
    np.testing.assert_allclose(rim.outward_shift(P, P), 0.0, atol=1e-6)
    uv = frame_uvs(np.c_[P, np.zeros(12)], _Identity(), (101, 81))
    np.testing.assert_allclose(rim.texture_positions(uv, (101, 81)), P, atol=1e-9)


class _Identity:
    """A camera that projects (x, y, z) to (x, y)."""

    @staticmethod
    def project(V):
        return np.array(V[:, :2], np.float64)


@pytest.fixture(scope="module")
def narrower(arkit_model):
    """The mean face at scale 25 (the target, ~270 px across) and at 24 and 21 (new faces 4 %
    and 16 % narrower), the same centre; the target frame: skin inside the target's
    silhouette with a dark edge 4 px wide just inside it (the hair beside a cheek the track's
    outline takes in), background out."""
    model = arkit_model
    topo = mesh_topology(model)
    zeros = np.zeros((1, 52), np.float32)
    target = mean_person_track(model, zeros, size=SIZE, scale=25.0)
    new = {k: mean_person_track(model, zeros, size=SIZE, scale=k) for k in (24.0, 21.0)}
    Vc = close_mouth(model.synthesize(target.weights_at(0)), topo)
    mask = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE)).mask
    from facetransfer.composite import _erode

    frame = np.empty((SIZE, SIZE, 3), np.uint8)
    frame[:] = BACK
    frame[mask] = EDGE
    frame[_erode(mask, 4)] = SKIN
    tex = FaceTexture(frame, frame_uvs(Vc, target.camera(0), (SIZE, SIZE)), 0)
    return model, topo, new, frame, tex, Vc


def test_a_narrower_face_keeps_the_targets_pixels_where_its_outline_was_drawn(narrower,
                                                                             monkeypatch):
    """The new face is 4 % narrower (its outline 4-6 px inside the target's): its outer
    band's texture is the target's dark edge. With the rule the band shows the target's own
    pixels (its skin); without it (:data:`facetransfer.rim.MOVED` out of reach) the dark edge
    is drawn inside the face. 16 % narrower, the outline moved farther than the band is wide
    (:data:`facetransfer.rim.REACH`): the band is left as rendered (what lies under it is no
    longer the edge of the target's face)."""
    model, topo, new, frame, tex, Vc = narrower

    def render(scale):
        V = model.synthesize(new[scale].weights_at(0))
        return rewrite_frame(frame, V, new[scale].camera(0), topo, tex, blend="none").image

    on, far = render(24.0), render(21.0)
    monkeypatch.setattr(rim, "MOVED", np.inf)
    off, far_off = render(24.0), render(21.0)
    kept = (on != off).any(axis=-1)
    assert kept.sum() > 500
    np.testing.assert_array_equal(on[kept], frame[kept])          # the target's own pixels
    # the band (~7 px) is wider than the dark edge (4 px)
    assert np.mean(np.abs(off[kept].astype(int) - EDGE).max(axis=1) < 40) > 0.6
    assert np.mean(np.abs(on[kept].astype(int) - SKIN).max(axis=1) < 10) > 0.8
    assert (far != far_off).any(axis=-1).sum() < 0.05 * kept.sum()


def test_the_same_outline_keeps_its_band(narrower):
    """The new face at the target's own pose and size: no band pixel's texture lies farther
    out than it does, so nothing is kept from the target for it (and a texture that is not
    the frame itself is never judged so)."""
    model, topo, new, frame, tex, Vc = narrower
    from facetransfer.track.result import Track  # noqa: F401 - the fixture's tracks

    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    r = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE))
    P = target.camera(0).project(Vc)
    shift = rim.outward_shift(P, rim.texture_positions(tex.uvs, (SIZE, SIZE)))
    assert not rim.inward_rim(r.mask, r, topo.faces, lambda idx: shift[idx]).any()
    inward = rim.inward_rim(r.mask, r, topo.faces, lambda idx: np.full(len(idx), 5.0))
    from facetransfer.composite import _erode

    k = max(2, int(round(rim.RIM * np.sqrt(r.mask.sum()))))
    np.testing.assert_array_equal(inward, r.mask & ~_erode(r.mask, k))
