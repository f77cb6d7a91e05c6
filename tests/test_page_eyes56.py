"""pageeyes56: the `view` page and the puppet hide a shut eye by the exports' per-face rule
(puppet_face.shut_gaps_at_blink): a face whose lids stay apart at eyeBlink 1 (the test model's
identity 1: 0.098 eye widths) no longer shows its shut eyes at 6-9 % light."""

from __future__ import annotations

import base64
import dataclasses

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES, activations_to_weights

from conftest import mean_person_track
from test_view import _drawn_eyes, _page_data

BLINKS = [ARKIT_NAMES.index(n) for n in ("eyeBlinkLeft", "eyeBlinkRight")]


def _still(model, make_arkit_track, identity: int):
    """A 2-frame track of ``identity`` at rest (every activation 0)."""
    track, a, _ = make_arkit_track(model, 2, identity=identity)
    z = np.zeros_like(a)
    return dataclasses.replace(track, blendshapes=z, weights={
        **track.weights, "expression": activations_to_weights(model, z)})


def _face(model, identity: int, blink: float) -> dict:
    """The weights of ``identity`` with both eyeBlinks at ``blink``."""
    a = np.zeros((1, 52))
    a[0, BLINKS] = blink
    return {"identity": model.factors[model.mode_index("identity")][identity],
            "expression": activations_to_weights(model, a)[0]}


def _landmark_ids(model) -> np.ndarray:
    """The model's iBUG-68 vertex ids."""
    return np.asarray(model.landmarks, np.int64)


def _old_light(gap: np.ndarray) -> np.ndarray:
    """The fixed rule before: smoothstep(0.08, 0.18, gap)."""
    u = np.clip((gap - 0.08) / (0.18 - 0.08), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@pytest.fixture(scope="module")
def still_pages(arkit_model, make_arkit_track, tmp_path_factory):
    """Track pages of identities 0 and 1 at rest."""
    from facetransfer.export.viewer import write_viewer

    d = tmp_path_factory.mktemp("pageeyes56")
    out = {}
    for ident in (0, 1):
        track = _still(arkit_model, make_arkit_track, ident)
        track.save(d / f"t{ident}.npz")
        out[ident] = (write_viewer(d / f"t{ident}.npz", d / f"t{ident}.html", model=arkit_model),
                      track)
    return out


@pytest.mark.slow
def test_the_page_hides_the_shut_eye_of_a_face_whose_lids_stay_apart(arkit_model, still_pages):
    """Identity 1 at eyeBlink 1 (gaps 0.098 / 0.095): the page hid its eyeballs only at 0.08 and
    drew them at 9 / 6 % light, where the glb and USD hide them. Now its shut gap is the
    exports' (gltf_eyes.shut_gaps) and the puppet's (puppet_face.face_shut_gaps) to 1e-6: the
    eyeballs hidden. At eyeBlink 0.9 the shade ramps from that gap, as the puppet's."""
    from facetransfer.export.common import identity_rig
    from facetransfer.export.gltf_eyes import shut_gaps
    from facetransfer.puppet_face import LID_SHADE, face_shut_gaps, lid_light

    page, track = still_pages[1]
    want = face_shut_gaps(arkit_model, _face(arkit_model, 1, 1.0))
    np.testing.assert_allclose(want, shut_gaps(arkit_model, identity_rig(track, arkit_model)),
                               atol=1e-12)
    assert np.all(want > LID_SHADE[0] + 0.015)
    drawn = _drawn_eyes(page, "frame=0&eyeBlinkLeft=1&eyeBlinkRight=1")
    assert [d["visible"] for d in drawn] == [False, False]
    assert [d["lit"] for d in drawn] == [0, 0]
    assert np.all(np.array([d["lid_gap"] for d in drawn]) > LID_SHADE[0])  # 0.08 alone: shown
    np.testing.assert_allclose([d["shut_gap"] for d in drawn], want, rtol=0, atol=1e-6)
    drawn = _drawn_eyes(page, "frame=0&eyeBlinkLeft=0.9&eyeBlinkRight=0.9")
    V = arkit_model.synthesize(_face(arkit_model, 1, 0.9))[np.asarray(arkit_model.landmarks)]
    lit = lid_light(V, want)
    assert np.all(lit > 0.05) and np.all(lit < _old_light(np.array([d["lid_gap"] for d in drawn])))
    assert all(d["visible"] for d in drawn)
    np.testing.assert_allclose([d["lit"] for d in drawn], lit, atol=2e-3)


@pytest.mark.slow
def test_a_face_whose_lids_close_below_008_keeps_the_pages_light(arkit_model, still_pages):
    """Identity 0 (gaps 0.052 / 0.053 at eyeBlink 1): its shut gap stays 0.08 exactly and the
    page's light at eyeBlink 0.8 is the fixed rule's."""
    page, _ = still_pages[0]
    drawn = _drawn_eyes(page, "frame=0&eyeBlinkLeft=0.8&eyeBlinkRight=0.8")
    assert [d["shut_gap"] for d in drawn] == [0.08, 0.08]
    gap = np.array([d["lid_gap"] for d in drawn])
    assert np.all(gap > 0.08)
    np.testing.assert_allclose([d["lit"] for d in drawn], _old_light(gap), atol=1e-12)


@pytest.mark.slow
def test_the_page_takes_the_shut_gap_of_the_identity_its_dials_show(arkit_model, still_pages):
    """The identity dials move the neutral the page draws: its shut gap is the rule
    (puppet_face.shut_gaps_at_blink) of that face (the page's float32 neutral and int16 dial
    offsets, its float64 eyeBlink offsets) to 1e-6, not the shown identity's before the dial."""
    from facetransfer.puppet_face import shut_gaps_at_blink

    page, _ = still_pages[1]
    data = _page_data(page.read_text())
    n3 = len(base64.b64decode(data["positions"])) // 4
    pos = np.frombuffer(base64.b64decode(data["positions"]), np.float32).astype(np.float64)
    q = np.frombuffer(base64.b64decode(data["targets"]), np.int16).reshape(-1, n3)
    t = data["target_names"].index("width")
    face = pos + 2.0 * q[t].astype(np.float32) * np.float32(data["target_scales"][t])
    face = face.reshape(-1, 3)
    E = data["eyes"]
    for k, d in E["blink"].items():
        face[int(k)] += d
    want = shut_gaps_at_blink(face[_landmark_ids(arkit_model)])
    before = _drawn_eyes(page, "frame=0&eyeBlinkLeft=1&eyeBlinkRight=1")
    drawn = _drawn_eyes(page, "frame=0&width=2&eyeBlinkLeft=1&eyeBlinkRight=1")
    got = [d["shut_gap"] for d in drawn]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    assert np.all(np.abs(np.subtract(got, [d["shut_gap"] for d in before])) > 1e-3)


def test_the_puppet_hides_the_shut_eye_of_a_face_whose_lids_stay_apart(arkit_model):
    """Identity 1 at eyeBlink 1 drawn by puppet_frames at 21 px an eye: before, 220 pixels of
    each eye fill showed the eyeball at 6-9 % light (lid_light with 0.08); now its lid light is
    0 by the face's own shut gap, the exports' (gltf_eyes.shut_gaps), and the fill is the
    lids' line (the skin's hue)."""
    from facetransfer.arkit import expression_rig
    from facetransfer.export.gltf_eyes import shut_gaps
    from facetransfer.puppet_face import face_shut_gaps, lid_light, puppet_face
    from facetransfer.puppet_video import puppet_frames
    from facetransfer.topology import mesh_topology

    w = _face(arkit_model, 1, 1.0)
    lm = _landmark_ids(arkit_model)
    face = puppet_face(arkit_model, mesh_topology(arkit_model, lips=False), weights=w)
    np.testing.assert_allclose(face.shut, shut_gaps(arkit_model, expression_rig(arkit_model, w)),
                               atol=1e-12)
    np.testing.assert_array_equal(face.shut, face_shut_gaps(arkit_model, w))
    V = arkit_model.synthesize(w)
    assert np.all(lid_light(V[lm]) > 0.05)                 # the fixed 0.08: lit
    np.testing.assert_array_equal(lid_light(V[lm], face.shut), [0, 0])
    a = np.zeros((1, 52), np.float32)
    a[0, BLINKS] = 1.0
    track = mean_person_track(arkit_model, a, size=512, scale=24.0)
    img = next(puppet_frames(track, arkit_model, w["identity"]))
    P = track.camera(0).project(V[lm])
    for eye in (range(36, 42), range(42, 48)):
        (x0, y0), (x1, y1) = np.floor(P[list(eye)].min(0)) - 1, np.ceil(P[list(eye)].max(0)) + 1
        px = img[int(y0):int(y1) + 1, int(x0):int(x1) + 1].reshape(-1, 3).astype(np.float64)
        g = px[:, 1] / np.maximum(px[:, 0], 1.0)
        assert np.all((g > 0.7) & (g < 0.9))                # skin and its line, no eyeball


def test_a_face_whose_lids_close_below_008_keeps_the_puppets_light_to_the_bit(arkit_model):
    """Identity 0 and the mean person (their lids 0.05-0.06 apart at eyeBlink 1): shut gap
    0.08 exactly, the light the same to the bit as the fixed rule's at every blink."""
    from facetransfer.puppet_face import face_shut_gaps, lid_gaps, lid_light

    lm = _landmark_ids(arkit_model)
    for ident in (0, None):
        for blink in (0.0, 0.5, 0.7, 0.75, 0.8, 0.9, 1.0):
            w = _face(arkit_model, 0, blink)
            if ident is None:
                w["identity"] = arkit_model.weight_mean("identity")
            shut = face_shut_gaps(arkit_model, w)
            np.testing.assert_array_equal(shut, [0.08, 0.08])
            V = arkit_model.synthesize(w)[lm]
            np.testing.assert_array_equal(lid_light(V, shut), _old_light(lid_gaps(V)))
            np.testing.assert_array_equal(lid_light(V, shut), lid_light(V))


def test_a_shut_gap_at_the_top_of_the_shade_steps_the_light():
    """shut_gaps_at_blink caps a face's shut gap at LID_SHADE[1] (0.18): lid_light is then 0 at
    and under it, 1 above (no 0 / 0); lids crossed at eyeBlink 1 keep 0.08."""
    from facetransfer.puppet_face import LID_SHADE, lid_gaps, lid_light, shut_gaps_at_blink

    P = np.zeros((68, 3))
    P[[36, 45], 0], P[[39, 42], 0] = (-2.0, 2.0), (-1.0, 1.0)    # eyes 1 wide
    P[[37, 38, 43, 44], 1] = 0.1
    P[[41, 40, 47, 46], 1] = -0.1                                 # lids 0.2 apart
    np.testing.assert_allclose(lid_gaps(P), [0.2, 0.2])
    shut = shut_gaps_at_blink(P)
    np.testing.assert_array_equal(shut, [LID_SHADE[1]] * 2)
    np.testing.assert_array_equal(lid_light(P, shut), [1, 1])       # 0.2 > 0.18: open
    narrower = P * [1, 0.85, 1]                                     # 0.17 apart
    np.testing.assert_array_equal(lid_light(narrower, shut), [0, 0])
    assert np.all(lid_light(narrower) > 0.9)                        # the fixed rule: lit
    crossed = P * [1, -1, 1]
    np.testing.assert_array_equal(shut_gaps_at_blink(crossed), [LID_SHADE[0]] * 2)


def test_a_model_without_eyeblinks_keeps_the_fixed_shut_gap(data_dir):
    """review56c: an ARKit model lacking the eyeBlink shapes (a manifest of some ARKit names) has
    zero eyeBlink rows, so "its lids at eyeBlink 1" were its open neutral's (0.25 eye widths):
    the shut gap went to LID_SHADE[1], 0.18, and the puppet, the glb/USD and the page hid the
    eyes of a look down (gap 0.154, lit 0.83 by the fixed rule). Now it keeps 0.08."""
    from conftest import _quick_ict_dataset
    from facetransfer.arkit import expression_rig, is_arkit_model
    from facetransfer.export.gltf_eyes import shut_gaps
    from facetransfer.export.viewer import eye_data
    from facetransfer.model import build_model
    from facetransfer.puppet_face import LID_SHADE, blink_shapes, face_shut_gaps, lid_light

    exprs = {"neutral": {}, "jawOpen": {"jawOpen": 1.0},
             "eyeLookDownLeft": {"eyeLookDown_L": 1.0}, "eyeLookDownRight": {"eyeLookDown_R": 1.0}}
    m = build_model(_quick_ict_dataset(data_dir, 2, exprs), {"identity": 2, "expression": 4},
                    refine=False)
    assert is_arkit_model(m) and blink_shapes(m) is None
    w = m.default_weights()
    np.testing.assert_array_equal(face_shut_gaps(m, w), [LID_SHADE[0]] * 2)
    rig = expression_rig(m, w)
    np.testing.assert_array_equal(shut_gaps(m, rig), [LID_SHADE[0]] * 2)
    assert eye_data(m, rig.neutral, list(ARKIT_NAMES), rig.deltas)["blink"] is None
    a = np.zeros((1, 52))
    a[0, [ARKIT_NAMES.index("eyeLookDownLeft"), ARKIT_NAMES.index("eyeLookDownRight")]] = 1.0
    P = m.synthesize({**w, "expression": activations_to_weights(m, a)[0]})[_landmark_ids(m)]
    light = lid_light(P, face_shut_gaps(m, w))
    np.testing.assert_array_equal(light, lid_light(P))
    assert np.all(light > 0.5)
