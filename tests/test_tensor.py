"""Tier 1 (exact identities) and tier 3 (tensorly reference) tests of facetransfer.tensor (§3)."""

import numpy as np
import pytest

from facetransfer import tensor as tl


def hand_2x3x4():
    # T[i, j, k] = 100 i + 10 j + k, easy to read off by hand.
    i, j, k = np.meshgrid(np.arange(2), np.arange(3), np.arange(4), indexing="ij")
    return (100 * i + 10 * j + k).astype(float)


def test_unfold_convention_hand_computed():
    T = hand_2x3x4()
    # mode 0: rows i, columns (j, k) with k fastest
    assert np.array_equal(tl.unfold(T, 0)[1], [100, 101, 102, 103, 110, 111, 112, 113, 120, 121, 122, 123])
    # mode 1: rows j, columns (i, k) with k fastest
    assert np.array_equal(tl.unfold(T, 1)[2], [20, 21, 22, 23, 120, 121, 122, 123])
    # mode 2: rows k, columns (i, j) with j fastest
    assert np.array_equal(tl.unfold(T, 2)[3], [3, 13, 23, 103, 113, 123])
    assert tl.unfold(T, 1).shape == (3, 8)


@pytest.mark.parametrize("mode", [0, 1, 2, -1])
def test_fold_inverts_unfold(mode):
    T = np.random.default_rng(0).normal(size=(2, 3, 4))
    assert np.array_equal(tl.fold(tl.unfold(T, mode), mode, T.shape), T)


def test_unfold_matches_tensorly():
    tensorly = pytest.importorskip("tensorly")
    T = np.random.default_rng(1).normal(size=(3, 4, 5, 2))
    for n in range(4):
        assert np.array_equal(tl.unfold(T, n), tensorly.unfold(T, n))


def test_mode_dot_definition_and_reference():
    rng = np.random.default_rng(2)
    T = rng.normal(size=(3, 4, 5))
    M = rng.normal(size=(6, 4))
    out = tl.mode_dot(T, M, 1)
    assert out.shape == (3, 6, 5)
    # every mode-1 vector v is replaced by M v (§3)
    assert np.allclose(out[2, :, 3], M @ T[2, :, 3], atol=1e-12)
    assert np.allclose(tl.unfold(out, 1), M @ tl.unfold(T, 1), atol=1e-12)
    tensorly = pytest.importorskip("tensorly")
    from tensorly.tenalg import mode_dot as tly_mode_dot

    assert np.allclose(out, tly_mode_dot(T, M, 1), atol=1e-12)


def test_mode_dot_vector_contracts_mode():
    T = hand_2x3x4()
    w = np.array([1.0, -1.0, 2.0])
    out = tl.mode_dot(T, w, 1)
    assert out.shape == (2, 4)
    assert np.allclose(out, T[:, 0] - T[:, 1] + 2 * T[:, 2])


def test_shape_errors_name_both_shapes():
    with pytest.raises(tl.TensorShapeError, match=r"\(2, 3, 4\) and \(5, 7\).*mode-1"):
        tl.mode_dot(hand_2x3x4(), np.zeros((5, 7)), 1)
    with pytest.raises(tl.TensorShapeError, match="out of range"):
        tl.unfold(hand_2x3x4(), 3)
    with pytest.raises(tl.TensorShapeError, match="cannot be folded"):
        tl.fold(np.zeros((3, 7)), 1, (2, 3, 4))
    with pytest.raises(tl.TensorShapeError, match="rank 5 for mode 1"):
        tl.nmode_svd(hand_2x3x4(), [None, 5, 2])
    assert issubclass(tl.TensorShapeError, ValueError)


def test_multi_mode_dot_order_independent():
    rng = np.random.default_rng(3)
    T = rng.normal(size=(5, 4, 3))
    A, B = rng.normal(size=(2, 4)), rng.normal(size=(6, 3))
    ref = tl.mode_dot(tl.mode_dot(T, A, 1), B, 2)
    assert np.allclose(tl.multi_mode_dot(T, [None, A, B]), ref, atol=1e-12)
    assert np.allclose(tl.multi_mode_dot(T, [A.T, B.T], [1, 2], transpose=True), ref, atol=1e-12)


def low_rank_tensor(shape, ranks, seed=0):
    rng = np.random.default_rng(seed)
    core = rng.normal(size=ranks)
    factors = [np.linalg.qr(rng.normal(size=(d, r)))[0] for d, r in zip(shape, ranks)]
    return tl.tucker_to_tensor(core, factors)


def test_nmode_svd_exact_for_low_rank_tensor():
    T = low_rank_tensor((40, 6, 5), (40, 3, 2))
    dec = tl.nmode_svd(T, [None, 3, 2], skip=(0,))
    assert dec.factors[0] is None and dec.core.shape == (40, 3, 2)
    assert np.linalg.norm(dec.to_tensor() - T) / np.linalg.norm(T) < 1e-10
    assert dec.errors[0] < 1e-10
    for U in dec.factors[1:]:
        assert np.allclose(U.T @ U, np.eye(U.shape[1]), atol=1e-12)


def test_nmode_svd_untruncated_is_exact_and_eq1_eq2():
    T = np.random.default_rng(4).normal(size=(30, 4, 5))
    dec = tl.nmode_svd(T)  # all modes factored, full rank: Eq. (1) then Eq. (2)
    assert np.allclose(dec.to_tensor(), T, atol=1e-10)
    # variance decreases along every mode of the core (§3)
    for n in range(3):
        energy = np.sum(tl.unfold(dec.core, n) ** 2, axis=1)
        assert np.all(np.diff(energy) <= 1e-9)


def test_factor_is_left_singular_basis_of_unfolding():
    T = np.random.default_rng(5).normal(size=(50, 6, 7))
    dec = tl.nmode_svd(T, [None, 3, 7], skip=(0,))
    U, s, _ = np.linalg.svd(tl.unfold(T, 1), full_matrices=False)
    # same subspace (signs may differ)
    assert np.allclose(np.abs(dec.factors[1].T @ U[:, :3]), np.eye(3), atol=1e-8)
    assert np.allclose(dec.eigenvalues[1], s ** 2, rtol=1e-9)


def test_variance_truncation():
    rng = np.random.default_rng(6)
    T = low_rank_tensor((60, 8, 6), (60, 2, 6), seed=6) + 1e-6 * rng.normal(size=(60, 8, 6))
    dec = tl.nmode_svd(T, skip=(0,), variance=0.999)
    assert dec.ranks[1] == 2
    assert tl.ranks_for_variance(np.array([3.0, 1.0, 0.0]), 0.75) == 1
    assert tl.ranks_for_variance(np.array([3.0, 1.0, 0.0]), 0.76) == 2
    with pytest.raises(ValueError, match=r"retained variance must be in \(0, 1\], got 1.5"):
        tl.ranks_for_variance(np.array([1.0]), 1.5)


def test_hooi_error_never_rises_and_improves_on_hosvd():
    rng = np.random.default_rng(7)
    T = rng.normal(size=(80, 7, 6, 5))
    dec = tl.hooi(T, [None, 3, 3, 2], skip=(0,), max_iter=30, tol=0)
    errs = np.array(dec.errors)
    assert len(errs) > 2
    assert np.all(np.diff(errs) <= 1e-12)
    assert errs[-1] < errs[0]  # ALS refines the truncated N-mode SVD (§3)
    # the reported error is the true reconstruction error
    true = np.linalg.norm(dec.to_tensor() - T) / np.linalg.norm(T)
    assert abs(true - errs[-1]) < 1e-10


def test_hooi_matches_tensorly_partial_tucker_error():
    tensorly = pytest.importorskip("tensorly")
    from tensorly.decomposition import partial_tucker

    rng = np.random.default_rng(8)
    T = rng.normal(size=(200, 6, 5)) + low_rank_tensor((200, 6, 5), (200, 2, 2), seed=8) * 30
    ours = tl.hooi(T, [None, 2, 3], skip=(0,), tol=1e-12, max_iter=100)
    (core, factors), _ = partial_tucker(T, rank=[2, 3], modes=[1, 2], n_iter_max=200, tol=1e-12,
                                        init="svd")
    rec = tl.multi_mode_dot(core, [None] + list(factors))
    theirs = np.linalg.norm(rec - T) / np.linalg.norm(T)
    assert ours.errors[-1] <= theirs + 1e-9
    assert abs(ours.errors[-1] - theirs) < 1e-4


def test_hooi_through_attribute_gram_equals_direct_sweeps(monkeypatch):
    rng = np.random.default_rng(9)
    T = rng.normal(size=(300, 5, 4, 6)) + 20 * low_rank_tensor((300, 5, 4, 6), (300, 2, 2, 3), seed=9)
    fast = tl.hooi(T, [None, 3, 2, 3], skip=(0,), tol=-1.0, max_iter=15)
    monkeypatch.setattr(tl, "GRAM_LIMIT", 0)  # force the sweeps over the full tensor
    slow = tl.hooi(T, [None, 3, 2, 3], skip=(0,), tol=-1.0, max_iter=15)
    assert np.allclose(fast.errors, slow.errors, atol=1e-10)
    for a, b in zip(fast.factors[1:], slow.factors[1:]):
        assert np.allclose(a @ a.T, b @ b.T, atol=1e-8)  # same subspaces
    assert np.allclose(fast.to_tensor(), slow.to_tensor(), atol=1e-8)
    assert np.all(np.diff(fast.errors) <= 1e-12)
    # the Gram's partial traces are the mode Grams of the data
    G, active = tl.attribute_gram(T, {0})
    assert active == (1, 2, 3)
    assert np.allclose(np.einsum("abcdbc->ad", G), tl.mode_gram(T, 1))


def test_tensor_shape_error_is_the_library_shape_error():
    """A researcher catching the project's ShapeError caught no mis-shaped mode product: the
    tensor module's error subclassed ValueError alone."""
    from facetransfer.errors import ShapeError

    T = np.zeros((2, 3, 4))
    with pytest.raises(ShapeError, match=r"\(2, 3, 4\) and \(5, 7\)"):
        tl.mode_dot(T, np.zeros((5, 7)), 1)


def test_modes_out_of_range_are_refused_not_wrapped():
    """fold's mode and nmode_svd's / hooi's skip wrapped around (mode 5 of a 3-way tensor was
    mode 2; skip=(3,) skipped mode 0) and returned a result for another mode."""
    T = np.random.default_rng(3).normal(size=(6, 4, 5))
    with pytest.raises(tl.TensorShapeError, match=r"mode 5 out of range.*\(6, 4, 5\)"):
        tl.fold(tl.unfold(T, 2), 5, T.shape)
    with pytest.raises(tl.TensorShapeError, match=r"mode 3 out of range.*\(6, 4, 5\)"):
        tl.nmode_svd(T, skip=(3,))
    with pytest.raises(tl.TensorShapeError, match=r"mode -4 out of range"):
        tl.hooi(T, [None, 2, 2], skip=(-4,))
    # negative modes in range still count from the end
    assert tl.nmode_svd(T, [2, 2, None], skip=(-1,)).ranks == (2, 2, 5)


def test_hooi_refuses_ranks_that_disagree_with_its_init():
    """hooi(T, ranks, init=d) silently kept init's ranks: asked for (2, 2, 2) from a (3, 2, 2)
    start it returned a (3, 2, 2) core."""
    T = np.random.default_rng(4).normal(size=(6, 4, 5))
    start = tl.nmode_svd(T, [3, 2, 2])
    with pytest.raises(tl.TensorShapeError, match="rank 2 asked for mode 0.*rank 3"):
        tl.hooi(T, [2, 2, 2], init=start)
    with pytest.raises(tl.TensorShapeError, match=r"factor of mode 1 has shape \(4, 2\), "
                                                   r"expected \(3, r\)"):
        tl.hooi(T[:, :3], init=start)
    refined = tl.hooi(T, [3, None, 2], init=start)      # agreeing (or open) ranks: as before
    assert refined.ranks == (3, 2, 2) and refined.errors[-1] <= start.errors[-1]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_tensor_is_named(bad):
    """A NaN in the data made nmode_svd raise numpy's LinAlgError "Eigenvalues did not
    converge", naming neither the tensor nor the cause."""
    from facetransfer.errors import FaceTransferError

    T = np.ones((3, 3, 3))
    T[1, 2, 0] = bad
    with pytest.raises(FaceTransferError, match=r"shape \(3, 3, 3\) holds NaN or infinite"):
        tl.nmode_svd(T)
    with pytest.raises(FaceTransferError, match="NaN or infinite"):
        tl.hooi(T, [2, 2, 2], skip=(0,))


@pytest.mark.parametrize("bad, said", [
    (np.ones((3, 3, 3)) + 1j, r"real numbers, got complex values of shape \(3, 3, 3\)"),
    (np.full((3, 3, 3), "x"), "real numbers, got text"),
    (np.zeros((0, 3, 3)), r"empty \(shape \(0, 3, 3\)\)"),
])
def test_complex_text_or_empty_tensor_is_named(bad, said):
    """A complex tensor was decomposed as its real part (a ComplexWarning only), text failed
    with numpy's "could not convert string to float", an empty one with "cannot reshape"."""
    from facetransfer.errors import ShapeError

    with pytest.raises(ShapeError, match=said):
        tl.nmode_svd(bad)
    with pytest.raises(ShapeError, match=said):
        tl.hooi(bad, skip=(0,))
