"""Tests of facetransfer.performance_edit: a track's expression edited (Vlasic et al. 2005,
Fig. 7E), exact on its weights or on an ARKit track's activations; the edits' text as ``edit``
takes it. (Moved out of tests/test_transfer.py with the edits' code.)"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer.performance_edit import (EditAdd, EditScale, edit_track, parse_add,
                                           parse_scale, ramp_envelope)
from facetransfer.transfer import TransferError
from test_transfer import make_track


def test_ramp_envelope_shape():
    """Full strength on START..END, both included; eased in and out over ``ramp`` frames
    outside it (before: ramps inside, so frames 5 and 15 took nothing and a 3-frame range
    reached 0.5 on one frame)."""
    e = ramp_envelope(20, 5, 15, 3)
    np.testing.assert_array_equal(e[5:16], 1.0)
    assert e[:2].sum() == 0 and e[19:].sum() == 0
    assert 0 < e[2] < e[3] < e[4] < 1 and 0 < e[18] < e[17] < e[16] < 1
    np.testing.assert_allclose(e[4], e[16])                  # symmetric about the range
    x = 1 - 1 / 4                                            # one frame outside, ramp 3
    np.testing.assert_allclose(e[4], x * x * (3 - 2 * x))
    np.testing.assert_array_equal(ramp_envelope(6, 1, 3, 0), [0, 1, 1, 1, 0, 0])
    np.testing.assert_array_equal(ramp_envelope(8, 3, 3, 2)[3], 1.0)   # a one-frame range
    np.testing.assert_array_equal(ramp_envelope(5, 0, 4, 8), 1.0)      # cut by the clip


def test_parse_edit_arguments():
    assert parse_add("frown@120-180") == EditAdd("frown", 120, 180, 1.0)
    assert parse_add("jaw_open*0.5@3-9") == EditAdd("jaw_open", 3, 9, 0.5)
    assert parse_scale("smile=1.5") == EditScale("smile", 1.5)
    for bad in ("frown", "frown@a-b"):
        with pytest.raises(TransferError, match=rf"^--add '{bad}': expected EXPRESSION@START-STOP, "
                                                r"e\.g\. frown@120-180$"):
            parse_add(bad)
    with pytest.raises(TransferError, match=r"^--add 'frown@9-3': the range ends \(3\) before it "
                                            r"starts \(9\)$"):
        parse_add("frown@9-3")
    for bad in ("smile", "=2", "smile=", "smile=1 x"):
        with pytest.raises(TransferError, match=rf"^--scale '{bad}': expected EXPRESSION=FACTOR, "
                                                r"e\.g\. smile=1\.5$"):
            parse_scale(bad)
    with pytest.raises(TransferError, match=r"^--scale 'smile=x': 'x' is not a number$"):
        parse_scale("smile=x")
    for bad in ("smile=inf", "smile=nan", "smile=1e999"):
        with pytest.raises(TransferError, match=rf"^--scale '{bad}': the factor must be finite$"):
            parse_scale(bad)
    assert parse_scale(" smile=+1.5e0 ") == EditScale("smile", 1.5)


def test_edit_add_is_exact_on_weights(quick_model, quick_track):
    m = quick_model
    d = m.training_weights("expression", "frown") - m.training_weights("expression", "neutral")
    new = edit_track(quick_track, m, add=[EditAdd("frown", 10, 20)], ramp=3)
    diff = new.weights["expression"] - quick_track.weights["expression"]
    e = ramp_envelope(30, 10, 20, 3)
    np.testing.assert_allclose(diff, e[:, None] * d[None, :], atol=1e-12)
    np.testing.assert_allclose(diff[10:21], np.tile(d, (11, 1)), atol=1e-12)  # the range: full
    np.testing.assert_array_equal(diff[:6], 0.0)
    np.testing.assert_array_equal(new.weights["identity"], quick_track.weights["identity"])


def test_edit_scale_is_exact_on_weights(quick_model, quick_track):
    m = quick_model
    n0 = m.training_weights("expression", "neutral")
    d = m.training_weights("expression", "smile") - n0
    rng = np.random.default_rng(1)
    perp = rng.normal(size=(30, d.size))
    perp -= (perp @ d)[:, None] * d / (d @ d)  # orthogonal to d
    a = rng.normal(size=30)
    tr = dataclasses.replace(quick_track, weights={
        "identity": quick_track.weights["identity"],
        "expression": n0 + a[:, None] * d + perp})
    new = edit_track(tr, m, scale=[EditScale("smile", 1.5)])
    np.testing.assert_allclose(new.weights["expression"], n0 + 1.5 * a[:, None] * d + perp,
                               atol=1e-10)


def test_edit_bad_input(quick_model, quick_track):
    with pytest.raises(TransferError, match="unknown expression 'grin'"):
        edit_track(quick_track, quick_model, add=[EditAdd("grin", 0, 5)])
    with pytest.raises(TransferError, match="outside the clip"):
        edit_track(quick_track, quick_model, add=[EditAdd("frown", 20, 40)])
    with pytest.raises(TransferError, match="another model"):
        edit_track(make_track(5), quick_model, add=[EditAdd("frown", 0, 2)])


def test_edits_made_in_python_are_checked_like_parsed_ones(quick_model, quick_track):
    """An EditAdd built directly with its range reversed was accepted (the envelope then never
    reached 1: 0.26 at most, the edit silently weak), and a NaN amount or factor surfaced as
    "track weights ... have non-finite values"."""
    m, tr = quick_model, quick_track
    with pytest.raises(TransferError, match=r"frown@20-10: the range ends \(10\) before"):
        edit_track(tr, m, add=[EditAdd("frown", 20, 10)])
    with pytest.raises(TransferError, match="frown@1-4: the amount must be finite"):
        edit_track(tr, m, add=[EditAdd("frown", 1, 4, float("nan"))])
    with pytest.raises(TransferError, match="smile=nan: the factor must be finite"):
        edit_track(tr, m, scale=[EditScale("smile", float("nan"))])


def test_edit_track_takes_one_edit_or_its_text(quick_model, quick_track):
    """add=EditAdd(...) (not in a list) raised TypeError "'EditAdd' object is not iterable";
    add=["frown@10-20"] raised AttributeError "'str' object has no attribute 'start'"."""
    m, tr = quick_model, quick_track
    want = edit_track(tr, m, add=[EditAdd("frown", 10, 20)], scale=[EditScale("smile", 1.5)])
    for add, scale in ((EditAdd("frown", 10, 20), EditScale("smile", 1.5)),
                       ("frown@10-20", "smile=1.5"), (["frown@10-20"], ("smile=1.5",))):
        got = edit_track(tr, m, add=add, scale=scale)
        np.testing.assert_array_equal(got.weights["expression"], want.weights["expression"])
    with pytest.raises(TransferError, match="an edit must be an EditAdd or its text, got int 3"):
        edit_track(tr, m, add=[3])


def test_edits_of_an_arkit_track_act_on_its_activations(arkit_model, make_arkit_track):
    """With the default kind of model (ARKit expressions), ``jawOpen=2`` doubles the jawOpen
    curve (clipped to 1) and leaves the 51 others to float precision (before: the projection
    on the weights counted the other shapes' part along jawOpen's direction, and the curve
    grew about six times); ``smile`` and ``frown`` name both sides; an unknown name lists the
    words too."""
    from facetransfer.arkit import ARKIT_NAMES as N
    from facetransfer.performance_edit import EditAdd, EditScale, edit_track

    track, a, _ = make_arkit_track(arkit_model, 40, seed=4)
    new = edit_track(track, arkit_model, scale=[EditScale("jawOpen", 2.0),
                                                EditScale("smile", 0.5)],
                     add=[EditAdd("frown", 10, 30, 0.25)], ramp=0)
    b, before = new.blendshapes.astype(np.float64), track.blendshapes.astype(np.float64)
    j = N.index("jawOpen")
    np.testing.assert_allclose(b[:, j], np.minimum(2 * before[:, j], 1.0), atol=1e-5)
    for side in ("Left", "Right"):
        k, f = N.index("mouthSmile" + side), N.index("mouthFrown" + side)
        np.testing.assert_allclose(b[:, k], 0.5 * before[:, k], atol=1e-5)
        np.testing.assert_allclose(b[10:31, f], np.minimum(before[10:31, f] + 0.25, 1.0),
                                   atol=1e-5)
        np.testing.assert_allclose(b[:10, f], before[:10, f], atol=1e-5)
    rest = [i for i, n in enumerate(N) if n not in ("jawOpen",) and "Smile" not in n
            and "Frown" not in n]
    np.testing.assert_allclose(b[:, rest], before[:, rest], atol=1e-5)
    with pytest.raises(TransferError, match="smile, frown, blink"):
        edit_track(track, arkit_model, scale=[EditScale("grin", 2.0)])
    with pytest.raises(TransferError, match="jawOpen=-2: an ARKit activation lies in 0..1"):
        edit_track(track, arkit_model, scale=[EditScale("jawOpen", -2.0)])
    # a shape the model lacks (the FaceKit has no tongue) was "added" and nothing changed
    with pytest.raises(TransferError, match="the model has no tongueOut shape"):
        edit_track(track, arkit_model, add=[EditAdd("tongueOut", 1, 3)])
    with pytest.raises(TransferError, match="did you mean jawOpen") as err:
        edit_track(track, arkit_model, scale=[EditScale("jawOpn", 2.0)])
    assert "tongueOut" not in str(err.value)                 # the list: the model's shapes
