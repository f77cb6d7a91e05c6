"""The source's mouth takes the face's colours by a gain (issue 13): painted lips at the mouth's
outline do not tint the teeth, and neither does the hue of the two people's skins."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
from facetransfer.render import rasterize
from facetransfer.mouth import mouth_ring_faces
from facetransfer.rewrite import FrameTextures, rewrite_frame
from facetransfer.rewrite_options import BlendOptions
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology
from facetransfer.render.cameras import WeakPerspective

SIZE = 256
SKIN_SOURCE = np.array([235.0, 205.0, 185.0])   # a pale, brightly lit face
SKIN_TARGET = np.array([190.0, 135.0, 115.0])   # a darker, pinker one
LIPSTICK = np.array([190.0, 40.0, 50.0])
TEETH = np.array([230.0, 228.0, 220.0])


@pytest.fixture(scope="module")
def scene(arkit_model):
    """The mean person with the mouth open, frontal; the closed mesh's fan, lips and ring."""
    model = arkit_model
    topo = mesh_topology(model)
    a = np.zeros((1, 52), np.float32)
    a[0, ARKIT_NAMES.index("jawOpen")] = 0.6
    w = model.default_weights()
    w["expression"] = activations_to_weights(model, a)[0]
    V = close_mouth(model.synthesize(w), topo)
    cam = WeakPerspective(scale=20.0, rotation=np.eye(3),
                          translation=np.array([SIZE / 2, SIZE / 2 - 40.0]))
    return model, topo, V, cam


def _source_frame(topo, V, cam, n_model_faces: int) -> np.ndarray:
    """The source: pale skin, the mouth's own triangles painted with lipstick, its gap teeth."""
    r = rasterize(V, topo.faces, cam, (SIZE, SIZE))
    img = np.tile(SKIN_SOURCE, (SIZE, SIZE, 1))
    mouth = np.isin(r.tri_id, topo.mouth_faces)
    img[mouth] = LIPSTICK
    img[r.tri_id >= n_model_faces] = TEETH            # the closing fan: the mouth's inside
    return img.astype(np.uint8)


def test_teeth_keep_their_hue_and_lips_take_the_skins_gain(scene):
    model, topo, V, cam = scene
    nF = len(model.faces)
    src = _source_frame(topo, V, cam, nF)
    target = np.empty((SIZE, SIZE, 3), np.uint8)
    target[:] = SKIN_TARGET.astype(np.uint8)
    uvs = frame_uvs(V, cam, (SIZE, SIZE))
    out = rewrite_frame(target, V, cam, topo,
                        FrameTextures(FaceTexture(target, uvs), mouth=FaceTexture(src, uvs)),
                        blending=BlendOptions("fast"))
    r = rasterize(V, topo.faces, cam, (SIZE, SIZE))
    inside = cv2.erode((r.tri_id >= nF).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert inside.sum() > 30
    teeth = out.image[inside].astype(float).mean(axis=0)
    # the teeth as bright as the target's skin is over the source's (the geometric mean of the
    # skins' ratios), their own hue kept: the skins' hue difference is the two people's
    grey = np.exp(np.mean(np.log(SKIN_TARGET / SKIN_SOURCE)))
    want = TEETH * grey
    assert np.abs(teeth - want).max() < 6, (teeth, want)
    np.testing.assert_allclose(teeth / teeth.sum(), TEETH / TEETH.sum(), atol=0.006)
    # the lips (the mouth's triangles outside the fan) take the skins' ratio per channel
    lips = np.isin(r.tri_id, topo.mouth_faces) & (r.tri_id < nF)
    lips = cv2.erode(lips.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert lips.sum() > 30
    lip = out.image[lips].astype(float).mean(axis=0)
    assert np.abs(lip - LIPSTICK * SKIN_TARGET / SKIN_SOURCE).max() < 8, lip
    # the skin around the mouth is the target's
    ring = np.isin(r.tri_id, np.flatnonzero(mouth_ring_faces(topo)))
    ring = cv2.erode(ring.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert np.abs(out.image[ring].astype(float).mean(axis=0) - SKIN_TARGET).max() < 4


def test_mouth_ring_surrounds_the_mouth(scene):
    model, topo, _, _ = scene
    ring = mouth_ring_faces(topo)
    assert ring.any() and not ring[topo.mouth_faces].any()
    mouth_vertices = np.unique(topo.faces[topo.mouth_faces])
    assert np.isin(topo.faces[ring], mouth_vertices).any(axis=1).sum() > 0   # touches it
    assert not np.isin(np.asarray(model.landmarks)[[36, 45, 8]], topo.faces[ring]).any()
