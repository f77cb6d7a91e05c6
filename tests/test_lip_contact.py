"""The lips' contact in the capture fit (facetransfer.track.lip_contact): the inner-lip gaps,
linear in the activations, held >= 0 where the box solution crosses the lips, and the box
solution itself kept, bit for bit, where it does not."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
from facetransfer.render import rotation_from_euler
from facetransfer.track.camera import Pose
from facetransfer.track.capture import CaptureOptions
from facetransfer.track.capture_points import Shape, sampler
from facetransfer.track.fit2d import Targets, box_qp
from facetransfer.track.lip_contact import LIP_PAIRS, contact_qp


def test_contact_qp_matches_a_general_solver():
    rng = np.random.default_rng(4)
    K, q = 12, 3
    M = rng.normal(size=(3 * K, K))
    G = M.T @ M + 0.1 * np.eye(K)
    h = rng.normal(size=K) * 5
    C = rng.normal(size=(q, K))
    lo, hi = np.zeros(K), np.ones(K)
    x0 = box_qp(G, h, np.zeros(K), lo=lo, hi=hi, tol=1e-12, sweeps=5000)
    d = C @ x0 + np.array([0.5, 0.3, -0.2])        # two of three violated by the box solution
    x = contact_qp(G, h, x0, lo, hi, C, d)
    ref = minimize(lambda a: 0.5 * a @ G @ a - h @ a, x0, jac=lambda a: G @ a - h,
                   bounds=list(zip(lo, hi)), method="SLSQP", options={"ftol": 1e-14,
                                                                       "maxiter": 500},
                   constraints=[{"type": "ineq", "fun": lambda a: C @ a - d,
                                 "jac": lambda a: C}]).x
    assert np.all(C @ x >= d - 1e-5) and np.all((x >= lo) & (x <= hi))
    np.testing.assert_allclose(x, ref, atol=2e-4)


def _frame(model, activations: dict, opt):
    """A frame's exact detections of the ``activations`` face (the arkit model's identity
    id02, a turned head) and its Shape."""
    a = np.zeros(52)
    for n, v in activations.items():
        a[ARKIT_NAMES.index(n)] = v
    ident = model.training_weights("identity", "id02")
    V = model.synthesize({"identity": ident, "expression": activations_to_weights(model, a)},
                         vertices=model.landmarks)
    pose = Pose(rotation_from_euler(10.0, 15.0, 0.0), 9.0, np.array([256.0, 240.0]))
    p = pose.project(V)
    shape = Shape(model, ident, sampler(model), opt)
    return shape, pose, Targets.stack([(p, np.ones(68))]), float(np.linalg.norm(p[36] - p[45]))


def _solve(shape, pose, targets, iod):
    return shape.solve(pose, targets, iod, shape.x0, None)


@pytest.mark.parametrize("crossed", [True, False])
def test_a_crossing_fit_holds_the_lips_apart_and_a_clean_one_is_unchanged(arkit_model,
                                                                         crossed):
    """A face whose true lips cross (mouthClose without jawOpen: the model's lips pass
    through each other) fits crossed without the contact and with a non-negative gap with it;
    a shut face whose lips do not cross fits the same, exactly, either way."""
    acts = ({"mouthClose": 0.12, "mouthRollLower": 0.3} if crossed else
            {"mouthClose": 0.01, "mouthPressLeft": 0.3, "mouthSmileRight": 0.4})
    off = replace(CaptureOptions(), lip_contact=False)
    s0, pose, tg, iod = _frame(arkit_model, acts, off)
    s1 = Shape(arkit_model, s0.identity, sampler(arkit_model), CaptureOptions())
    x0, x1 = _solve(s0, pose, tg, iod), _solve(s1, pose, tg, iod)
    assert s0.lips is None and s1.lips is not None
    gap0, gap1 = s1.lips.gaps(x0), s1.lips.gaps(x1)
    assert len(gap1) == len(LIP_PAIRS)
    if crossed:
        assert gap0.min() < -0.02                   # model units (cm): crossed by > 0.2 mm
        assert gap1.min() >= -1e-4
        assert np.all((x1 >= 0) & (x1 <= 1))
    else:
        assert gap0.min() > 0
        np.testing.assert_array_equal(x1, x0)


def test_an_identity_whose_lips_cross_at_rest_keeps_its_own_contact():
    """Where the neutral face's own gap is negative the expression is held to that gap, not
    made to part the lips; a gap above it is left alone."""
    from facetransfer.track.lip_contact import lip_contact

    def lip_contact_of(g0, C):
        """The LipContact of a one-pair rig: upper lip at ``g0``, the lower one at 0."""
        N = np.zeros((68, 3))
        N[27, 1], N[62, 1] = 1.0, g0[0]
        D = np.zeros((C.shape[1], 68, 3))
        D[:, 62, 1] = C[0]
        lips = lip_contact(N, D)
        return type(lips)(lips.g0[1:2], lips.C[1:2], lips.floor[1:2])

    G, h = np.diag([2.0, 1.0]), np.array([0.6, 0.2])
    lo, hi = np.zeros(2), np.ones(2)
    lips = lip_contact_of(np.array([-0.05]), np.array([[-1.0, 0.0]]))   # a_0 closes the lips
    x0 = box_qp(G, h, np.zeros(2), lo=lo, hi=hi, tol=1e-12)           # (0.3, 0.2)
    np.testing.assert_allclose(lips.floor, [-0.05])
    x = lips.solve(G, h, x0, lo, hi)
    np.testing.assert_allclose(lips.gaps(x), [-0.05], atol=1e-6)     # not 0
    np.testing.assert_allclose(x[1], 0.2, atol=1e-9)
    open_ = lip_contact_of(np.array([0.5]), np.array([[-1.0, 0.0]]))
    assert open_.solve(G, h, x0, lo, hi) is x0
