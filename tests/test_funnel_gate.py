"""The funnel's gate by the lips' gap (funnel56): ARKit's mouthFunnel rounds lips that are
open, so the capture's solve holds it near 0 where the detected lips are shut
(facetransfer.track.capture_frame.lips_gap / lips_gate, facetransfer.track.capture.funnel_ridges)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.errors import ShapeError
from facetransfer.render import rotation_from_euler
from facetransfer.track.capture import CaptureOptions, funnel_ridges
from facetransfer.track.capture_frame import LIPS_APART, LIPS_SHUT, lips_gap, lips_gate

FUNNEL, PUCKER = ARKIT_NAMES.index("mouthFunnel"), ARKIT_NAMES.index("mouthPucker")


def _mouth(gaps: tuple[float, float, float], eye: float = 10.0) -> np.ndarray:
    """iBUG points (68, 2): the outer eye corners ``eye`` apart, the upper inner lip (61-63)
    at y = 1 and the lower one (67, 66, 65) ``gaps`` below it; the rest at random."""
    P = np.random.default_rng(0).normal(size=(68, 2))
    P[36], P[45] = (0.0, 0.0), (eye, 0.0)
    for k, (u, lo) in enumerate(((61, 67), (62, 66), (63, 65))):
        P[u] = (3.0 + k, 1.0)
        P[lo] = (3.0 + k, 1.0 + gaps[k])
    return P


def test_lips_gap_is_the_inner_lips_mean_gap_over_the_eye_corners_at_any_similarity():
    P = _mouth((0.5, 1.0, 1.5), eye=10.0)
    R = rotation_from_euler(0, 0, 30)[:2, :2]
    moved = 3.0 * P @ R.T + np.array([120.0, -40.0])
    np.testing.assert_allclose(lips_gap(np.stack([P, moved])), [0.1, 0.1], rtol=1e-12)
    P[62] = np.nan
    assert np.isnan(lips_gap(P[None]))[0]
    with pytest.raises(ShapeError, match=r"\(2, 68\)"):
        lips_gap(np.zeros((2, 68)))


def test_lips_gate_is_one_when_shut_zero_when_apart_and_linear_between():
    mid = (LIPS_SHUT + LIPS_APART) / 2
    gaps = np.array([0.0, LIPS_SHUT, mid, LIPS_APART, 0.2, np.nan])
    np.testing.assert_allclose(lips_gate(gaps), [1.0, 1.0, 0.5, 0.0, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="apart > shut"):
        lips_gate(gaps, shut=0.05, apart=0.05)


def test_funnel_ridges_weigh_the_funnel_alone_by_how_shut_the_lips_are(arkit_model):
    from facetransfer.track import capture_points
    from facetransfer.track.capture_points import Shape

    opt = CaptureOptions()
    shape = Shape(arkit_model, np.asarray(arkit_model.default_weights()["identity"]),
                  capture_points.sampler(arkit_model), opt)
    eye = 10.0
    mid = (LIPS_SHUT + LIPS_APART) / 2
    pts = np.stack([_mouth((g, g, g), eye) for g in (0.0, mid * eye, 0.1 * eye)])
    ridges = funnel_ridges(shape, pts, opt)                              # (3, K)
    k = int(np.flatnonzero(shape.used == FUNNEL)[0])
    np.testing.assert_allclose(ridges[:, k], opt.funnel_gate * opt.expression_prior
                               * np.array([1.0, 0.5, 0.0]), atol=1e-12)
    assert opt.funnel_gate * opt.expression_prior == pytest.approx(1.0)   # the default: 100 x 0.01
    assert not np.delete(ridges, k, axis=1).any()
    assert funnel_ridges(shape, pts, CaptureOptions(funnel_gate=0.0)) is None


def test_shut_lips_pushed_out_are_not_read_as_a_funnel(arkit_model, data_dir):
    """funnel56: ``driving_d9``'s frames 168-243 are a pucker with the lips shut (Face
    Landmarker: funnel 0.009, pucker 0.67; the detected lips' gap 0.003-0.011 of the eye
    corners' distance). Without the gate this model read a funnel up to 0.121 there (median
    0.025); with it, at most 0.030 (median 0.002). The pucker is still read."""
    from facetransfer.track.capture import capture_video

    tr = capture_video(data_dir / "video" / "driving_d9.mp4", arkit_model)
    A = tr.blendshapes[168:244]
    assert not tr.lost.any()
    assert A[:, FUNNEL].max() < 0.06
    assert np.median(A[:, PUCKER]) > 0.15


def test_a_real_o_keeps_its_funnel(arkit_model, data_dir):
    """funnel56: ``driving_d6``'s frames 768-792 are a real "O" (Face Landmarker's funnel
    0.22-0.51, the lips 0.12-0.16 apart): the gate does not touch them (this model, the clip's
    first 800 frames: median 0.227 with the gate and without)."""
    from facetransfer.track.capture import capture_video

    video = data_dir / "video" / "driving_d6.mp4"
    on = capture_video(video, arkit_model, max_frames=800).blendshapes[768:793, FUNNEL]
    assert np.median(on) > 0.2
