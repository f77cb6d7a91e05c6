"""Semantic identity dials (§5 intro after Allen et al. 2003): measurements, regression, editing."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.dials import (MEASUREMENTS, DialError, dial_track, identity_measurements,
                                learn_dials, measure, parse_dial_values)


@pytest.fixture(scope="module")
def dials(arkit_model):
    return learn_dials(arkit_model)


def test_measure_exact():
    L = np.zeros((68, 3))
    L[0], L[16] = (-7.0, 0, 0), (7.0, 0, 0)  # face width 14
    L[36:42] = (-3.0, 1.0, 0.0)
    L[42:48] = (3.0, 1.0, 0.0)  # eye centres 6 apart
    L[51], L[62], L[57], L[66] = (0, 1.0, 0), (0, 0.4, 0), (0, -1.2, 0), (0, -0.4, 0)
    m = dict(zip(MEASUREMENTS, measure(L)))
    assert m["width"] == pytest.approx(14.0)
    assert m["eye_spacing"] == pytest.approx(6.0)
    assert m["lip_fullness"] == pytest.approx(0.6 + 0.8)
    with pytest.raises(DialError, match=r"\(\.\.\., 68, 3\)"):
        measure(np.zeros((10, 3)))


def test_dials_explain_measurements(arkit_model, dials):
    assert dials.names == tuple(MEASUREMENTS) and dials.unit == "cm"
    for d in dials.dials:
        assert d.direction.shape == (arkit_model.ranks[0],)
        assert 0.9 <= d.r2 <= 1.0 + 1e-12, d
        assert d.r2_loo > 0.5, d  # predictive, not just a fit of 6 identities
        assert d.sigma > 0 and d.effect > 0


def test_one_unit_changes_the_measurement_by_the_stated_amount(arkit_model, dials):
    W = arkit_model.factors[0]
    for j, d in enumerate(dials.dials):
        base = W[3]  # a training identity, not the mean face the effect was stated on
        m0, m1, m2 = identity_measurements(arkit_model, np.stack(
            [base, base + d.direction, base + 2 * d.direction]))[:, j]
        # distances are nearly, not exactly, linear in the weights (lips and chin least)
        assert m1 - m0 == pytest.approx(d.effect, rel=0.2), d.name
        assert m2 - m0 == pytest.approx(2 * (m1 - m0), rel=0.05), d.name
    for d in dials.dials:  # the unit is one standard deviation, on the mean face
        assert d.effect == pytest.approx(d.sigma, rel=0.02), d.name


def test_dial_track_and_values(arkit_model, dials, make_arkit_track):
    track, a, _ = make_arkit_track(arkit_model, 6)
    new = dial_track(track, arkit_model, {"width": 1.5, "nose_length": -1.0}, dials=dials)
    want = track.weights["identity"] + 1.5 * dials.get("width").direction \
        - dials.get("nose_length").direction
    np.testing.assert_allclose(new.weights["identity"], want, atol=1e-12)
    np.testing.assert_array_equal(new.weights["expression"], track.weights["expression"])
    np.testing.assert_allclose(new.blendshapes, a, atol=1e-5)  # expressions untouched
    assert np.abs(new.landmarks2d - track.landmarks2d).max() > 1.0  # re-projected
    with pytest.raises(DialError, match="unknown identity dial 'wdth'.*width"):
        dial_track(track, arkit_model, {"wdth": 1.0}, dials=dials)
    assert parse_dial_values("width=+1.5, jaw_width=-2") == {"width": 1.5, "jaw_width": -2.0}
    with pytest.raises(DialError, match=r"width=1e9 is beyond the dials' range of -5 to \+5"):
        parse_dial_values("jaw_width=-5,width=1e9")
    assert parse_dial_values("width=-5") == {"width": -5.0}
    for bad in ("width", "width=abc", "=1", ""):
        with pytest.raises(DialError):
            parse_dial_values(bad)


def test_too_few_identities(arkit_model):
    import dataclasses

    small = dataclasses.replace(arkit_model, factors=(arkit_model.factors[0][:2],
                                                      arkit_model.factors[1]),
                                labels=(arkit_model.labels[0][:2], arkit_model.labels[1]))
    with pytest.raises(DialError, match="at least 3"):
        learn_dials(small)


def test_dials_cli(arkit_model, make_arkit_track, tmp_path, capsys):
    from facetransfer.track import Track

    mp, tp = tmp_path / "m.npz", tmp_path / "t.npz"
    arkit_model.save(mp)
    track, _, _ = make_arkit_track(arkit_model, 5)
    track.save(tp)
    assert main(["model", "dials", str(mp), "--out", str(tmp_path / "dials.png")]) == 0
    out = capsys.readouterr().out
    assert "width" in out and "lip_fullness" in out and "R2" in out
    from PIL import Image

    assert Image.open(tmp_path / "dials.png").size[1] > 10 * 100
    assert main(["edit", str(tp), "--model", str(mp), "--identity-dials", "width=+1.5",
                 "--out", str(tmp_path / "t2.npz")]) == 0
    capsys.readouterr()
    new = Track.load(tmp_path / "t2.npz")
    d = learn_dials(arkit_model).get("width").direction
    np.testing.assert_allclose(new.weights["identity"], track.weights["identity"] + 1.5 * d,
                               atol=1e-9)
    assert main(["edit", str(tp), "--model", str(mp), "--identity-dials", "girth=1",
                 "--out", str(tmp_path / "t3.npz")]) == 2
    err = capsys.readouterr().err
    assert "unknown identity dial 'girth'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t3.npz").exists()


def test_transfer_dials_need_an_identity(arkit_model, data_dir, tmp_path, capsys):
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    clip = data_dir / "video" / "face_2.mp4"
    assert main(["transfer", "--target", str(clip), "--model", str(mp), "--identity-dials",
                 "width=1", "--out", str(tmp_path / "o.mp4")]) == 2
    assert "--identity-dials needs the identity" in capsys.readouterr().err
    assert main(["transfer", "--target", str(clip), "--model", str(mp), "--identity-label",
                 "id01", "--identity-dials", "nope=1", "--out", str(tmp_path / "o.mp4")]) == 2
    assert "unknown identity dial" in capsys.readouterr().err


def test_dials_that_predict_nothing_are_said(arkit_model, dials, tmp_path, capsys, monkeypatch):
    """A dial whose leave-one-out R2 is at most 0 (a model of too few identities: ict-trilinear's
    16 gave -0.138 on every dial, exactly the mean's score) is said by `model dials` and warned
    of when `transfer --identity-dials` uses it; dials that predict are not."""
    import dataclasses

    from facetransfer import dials as dials_module
    assert dials.unreliable() == [d.name for d in dials.dials if not d.r2_loo > 0]
    first = dials.dials[0]
    poor = dataclasses.replace(dials, dials=(dataclasses.replace(first, r2_loo=-0.138),)
                               + dials.dials[1:])
    assert poor.unreliable() == [first.name] and poor.unreliable(["nothing"]) == []
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    monkeypatch.setattr(dials_module, "learn_dials", lambda m: poor)
    assert main(["model", "dials", str(mp)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1].startswith(f"note: {first.name}: leave-one-out R2 <= 0")
