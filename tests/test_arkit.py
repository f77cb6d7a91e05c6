"""ARKit blendshapes as the expression mode (facetransfer.arkit) and the ict-arkit data set."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest

from facetransfer.arkit import (ARKIT_NAMES, MEDIAPIPE_NAMES, activations_to_weights,
                                arkit_rows, expression_rig, is_arkit_model,
                                load_facekit_mapping, weights_to_activations)
from facetransfer.errors import ShapeError


def test_names_are_apples_52():
    assert len(ARKIT_NAMES) == 52 and len(set(ARKIT_NAMES)) == 52
    assert ARKIT_NAMES[-1] == "tongueOut" and ARKIT_NAMES[:51] == MEDIAPIPE_NAMES
    assert list(MEDIAPIPE_NAMES) == sorted(MEDIAPIPE_NAMES)  # MediaPipe's order is alphabetical
    for n in ("eyeBlinkLeft", "jawOpen", "mouthSmileRight", "browInnerUp", "cheekPuff"):
        assert n in ARKIT_NAMES


def test_mediapipe_reports_exactly_these_names(data_dir):
    """MediaPipe's own blendshape categories on a real frame, in its order."""
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    from facetransfer.assets import asset_path
    from facetransfer.io.video import iter_frames

    img = next(iter_frames(data_dir / "video" / "WDA_KatieHill_000.mp4"))
    opts = vision.FaceLandmarkerOptions(base_options=BaseOptions(
        model_asset_path=str(asset_path("face_landmarker"))), output_face_blendshapes=True,
        num_faces=1)
    with vision.FaceLandmarker.create_from_options(opts) as lm:
        res = lm.detect(mp.Image(image_format=mp.ImageFormat.SRGB,
                                 data=np.ascontiguousarray(img)))
    names = [c.category_name for c in res.face_blendshapes[0]]
    assert names == ["_neutral"] + list(MEDIAPIPE_NAMES)


def test_mapping_covers_every_facekit_shape():
    from facetransfer.datasets.ict import ict_expression_names

    table = load_facekit_mapping()
    used = {f for w in table["shapes"].values() for f in w}
    dropped = set(table["dropped"])
    assert used | (dropped - {"PupilDilate_L", "PupilDilate_R"}) == set(ict_expression_names())
    assert set(table["shapes"]) | set(table["not_modelled"]) == set(ARKIT_NAMES)
    assert table["shapes"]["browInnerUp"] == {"browInnerUp_L": 1.0, "browInnerUp_R": 1.0}
    assert table["shapes"]["eyeBlinkLeft"] == {"eyeBlink_L": 1.0}


def test_arkit_model_labels_and_exact_conversion(arkit_model):
    m = arkit_model
    assert is_arkit_model(m)
    labels = m.labels[m.mode_index("expression")]
    assert labels[0] == "neutral" and labels[1:] == MEDIAPIPE_NAMES
    rows = arkit_rows(m)
    assert rows[-1] == -1 and np.all(rows[:51] == np.arange(1, 52))
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 1, (5, 52))
    a[:, -1] = 0.0  # tongueOut: not modelled
    w = activations_to_weights(m, a)
    np.testing.assert_allclose(weights_to_activations(m, w), a, atol=1e-9)
    with pytest.raises(ShapeError):
        activations_to_weights(m, a[:, :51])


def test_rig_reproduces_the_training_meshes(arkit_model_full):
    """The untruncated model's rig of a training identity gives its training shapes exactly."""
    m = arkit_model_full
    w = m.like(identity="id01")
    rig = expression_rig(m, w)
    for j in (ARKIT_NAMES.index("jawOpen"), ARKIT_NAMES.index("eyeBlinkLeft")):
        a = np.zeros(52)
        a[j] = 1.0
        ref = m.synthesize(m.like(identity="id01", expression=ARKIT_NAMES[j]))
        np.testing.assert_allclose(rig.shape(a), ref, atol=1e-8)
    np.testing.assert_allclose(rig.shape(np.zeros(52)),
                               m.synthesize(m.like(identity="id01", expression="neutral")),
                               atol=1e-8)


def test_rig_refuses_activations_of_another_length(arkit_model):
    """ExpressionRig.shape of 51 activations raised numpy's "shape-mismatch for sum"."""
    rig = expression_rig(arkit_model, arkit_model.default_weights())
    with pytest.raises(ShapeError, match=r"activations must be \(\.\.\., 52\).*got \(4, 51\)"):
        rig.shape(np.zeros((4, 51)))
    assert rig.shape(np.zeros((4, 52))).shape == (4,) + rig.neutral.shape


def test_eye_blink_left_closes_the_eye_on_the_image_right(arkit_model):
    """ARKit and MediaPipe mean the subject's own left: in a frontal picture, the image's right."""
    from facetransfer.render import render_model

    m = arkit_model
    base = render_model(m, m.like(identity="generic"), size=(256, 256)).image.astype(float)
    for name, right in (("eyeBlinkLeft", True), ("eyeBlinkRight", False)):
        img = render_model(m, m.like(identity="generic", expression=name),
                           size=(256, 256)).image.astype(float)
        diff = np.abs(img - base).sum(axis=2) > 30
        ys, xs = np.nonzero(diff)
        assert len(xs) > 20
        assert (xs.mean() > 128) == right
        assert ys.mean() < 128  # the eyes, in the upper half


def test_recipe_file_lists_arkit_dataset():
    from facetransfer.datasets.ict import load_recipes

    rec = load_recipes()
    spec = rec["datasets"]["ict-arkit"]
    assert spec["expressions"] == ["neutral"] + list(MEDIAPIPE_NAMES)
    assert spec["n_identities"] >= 50
    raw = json.loads(resources.files("facetransfer.data").joinpath("ict_recipes.json").read_text())
    assert raw["datasets"]["ict-arkit"]["default_ranks"]["expression"] == 52


def test_why_a_model_gives_no_activations(arkit_model, quick_model):
    """An ict-arkit model whose expression rank is truncated carries the ARKit names but no
    activations: said as such (before: "its expressions are not ARKit blendshapes", which
    they are); a model of other expressions is said to be one; the default kind, nothing."""
    from facetransfer.arkit import arkit_shortfall
    from facetransfer.model import build_model

    assert arkit_shortfall(arkit_model) is None
    assert arkit_shortfall(quick_model).startswith("the model's expressions are not ARKit "
                                                   "blendshapes")
    from facetransfer.datasets.ict import build_ict_dataset

    ds = build_ict_dataset("ict-arkit", n_identities=6, use_cache=True)
    short = build_model(ds, {"identity": 3, "expression": 20}, refine=False)
    n = len(short.labels[short.mode_index("expression")])     # neutral and the shapes
    assert arkit_shortfall(short) == (f"the model's expression mode keeps 20 of its {n} "
                                      "components "
                                      f"(the ARKit activations need at least {n - 1}: build it "
                                      "without truncating the expression rank)")
