"""The lips' contact in the capture fit (facetransfer.track.lip_contact): the inner-lip gaps,
linear in the activations, held >= 0 where the box solution crosses the lips, and the box
solution itself kept, bit for bit, where it does not."""

from __future__ import annotations

import itertools
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


def _qp_by_active_sets(G, h, lo, hi, C, d):
    """The exact minimiser of the box QP with ``C a >= d`` by enumerating active sets (each
    activation free, at ``lo`` or at ``hi``; each row of ``C`` held or not): the least
    objective among the feasible stationary points (a small, independent reference)."""
    K, q, best = len(h), len(d), None
    for st in itertools.product(range(3), repeat=K):
        fixed = np.array([s > 0 for s in st])
        xf = np.where(np.array(st) == 1, lo, hi) * fixed
        F = np.flatnonzero(~fixed)
        for held in itertools.product((False, True), repeat=q):
            A = np.flatnonzero(held)
            n, m = len(F), len(A)
            M, b = np.zeros((n + m, n + m)), np.zeros(n + m)
            M[:n, :n], b[:n] = G[np.ix_(F, F)], h[F] - G[F] @ xf
            M[:n, n:], M[n:, :n] = -C[np.ix_(A, F)].T, C[np.ix_(A, F)]
            b[n:] = d[A] - C[A] @ xf
            if abs(np.linalg.det(M)) < 1e-12:
                continue
            x = xf.copy()
            x[F] = np.linalg.solve(M, b)[:n]
            if np.all((x >= lo - 1e-9) & (x <= hi + 1e-9)) and np.all(C @ x >= d - 1e-9):
                f = 0.5 * x @ G @ x - h @ x
                best = (f, x) if best is None or f < best[0] else best
    return best[1]


def test_contact_qp_is_the_exact_minimiser_on_random_instances():
    """Against the enumeration of active sets on small instances where most activations sit
    on a bound and the gaps' free activations cannot move them (the semi-smooth Newton over
    the free activations alone stopped there or cycled: 69 of 200 such instances wrong)."""
    rng = np.random.default_rng(0)
    for _ in range(60):
        K, q = 4, int(rng.integers(1, 4))
        M = rng.normal(size=(2 * K, K))
        G, h = M.T @ M + 0.05 * np.eye(K), rng.normal(size=K) * 3
        C, lo, hi = rng.normal(size=(q, K)), np.zeros(K), np.ones(K)
        x0 = box_qp(G, h, np.zeros(K), lo=lo, hi=hi, tol=1e-13, sweeps=20000)
        d = C @ x0 + rng.uniform(-0.3, 0.6, size=q)
        try:
            ref = _qp_by_active_sets(G, h, lo, hi, C, d)
        except TypeError:                                    # no feasible point
            continue
        np.testing.assert_allclose(contact_qp(G, h, x0, lo, hi, C, d), ref, atol=1e-6)


def test_contact_qp_degenerate_cases():
    """A gap whose free activations cannot move it (the exact answer moves one at its bound),
    parallel rows, a zero row, a gap the box cannot reach (as close as the box allows), gaps
    that cannot hold together (finite, in the box),
    an already-feasible start (kept) and a huge, ill-conditioned normal matrix."""
    G, lo, hi = np.eye(2), np.zeros(2), np.ones(2)
    h = np.array([-1.0, 0.5])                                 # box solution (0, 0.5)
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, np.array([[1.0, 0.0]]), np.array([0.5]))
    np.testing.assert_allclose(x, [0.5, 0.5], atol=1e-7)
    C2 = np.array([[1.0, 0.0], [2.0, 0.0]])                   # parallel: a_0 >= 0.3, a_0 >= 0.25
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, C2, np.array([0.3, 0.5]))
    np.testing.assert_allclose(x, [0.3, 0.5], atol=1e-7)
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, np.array([[1.0, 0.0], [0.0, 0.0]]),
                   np.array([0.5, 0.1]))                      # 0 >= 0.1: cannot hold
    np.testing.assert_allclose(x, [0.5, 0.5], atol=1e-7)      # the other one held
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, np.array([[1.0, 0.0], [-1.0, 0.0]]),
                   np.array([0.6, -0.4]))                     # a_0 >= 0.6 and <= 0.4: not both
    assert np.all(np.isfinite(x)) and np.all((x >= lo) & (x <= hi))
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, np.array([[1.0, 1.0]]), np.array([3.0]))
    np.testing.assert_allclose(x, [1.0, 1.0])                 # a_0 + a_1 <= 2 < 3: the corner
    x = contact_qp(G, h, np.array([0.0, 0.5]), lo, hi, np.array([[0.0, 1.0]]), np.array([0.1]))
    np.testing.assert_allclose(x, [0.0, 0.5], atol=1e-9)      # feasible: the box solution
    Gi = 1e6 * np.array([[1.0, 0.998], [0.998, 1.0]])        # huge, condition number 1e3
    hi_ = Gi @ np.array([0.5, 0.5])
    x = contact_qp(Gi, hi_, np.zeros(2), lo, hi, np.array([[1.0, -1.0]]), np.array([0.4]))
    ref = minimize(lambda a: 0.5 * a @ Gi @ a - hi_ @ a, np.array([0.7, 0.3]),
                   jac=lambda a: Gi @ a - hi_, bounds=[(0, 1)] * 2, method="SLSQP",
                   constraints=[{"type": "ineq", "fun": lambda a: a[0] - a[1] - 0.4}],
                   options={"ftol": 1e-15, "maxiter": 500}).x
    np.testing.assert_allclose(x, ref, atol=1e-5)


def test_a_model_that_is_not_arkit_named_fits_without_the_contact(quick_model):
    """The paper's per-mode models (a bilinear ICT model here) have no activations to bound:
    their Shape says so (``lips`` None, as with the option off) and solves as before."""
    ident = quick_model.training_weights("identity", quick_model.labels[0][0])
    shape = Shape(quick_model, ident, sampler(quick_model), CaptureOptions())
    assert not shape.arkit and shape.lips is None
    V = shape.points(shape.x0)[:68]
    pose = Pose(np.eye(3), 9.0, np.array([256.0, 240.0]))
    p = pose.project(V)
    x = shape.solve(pose, Targets.stack([(p, np.ones(68))]), float(np.linalg.norm(p[36] - p[45])),
                    shape.x0, None)
    assert np.all(np.isfinite(x)) and x.shape == shape.x0.shape


def test_loading_the_kernels_leaves_scipys_optimiser_unimported():
    """The tracker's start (``load_kernels``, before the transfer's fork) warms the contact's
    Newton steps without importing SciPy's optimiser (0.17 s), which only a failed Newton
    solve calls."""
    import subprocess
    import sys

    code = ("import sys; from facetransfer.track.capture import load_kernels; load_kernels(); "
            "print('scipy.optimize' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
