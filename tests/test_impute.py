"""Tests of §4.4 missing-data imputation (facetransfer.impute) and ``facetransfer impute eval``."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import impute as im
from facetransfer import tensor as tl
from facetransfer.datasets import FaceDataset
from facetransfer.errors import DatasetError


# ----------------------------------------------------------------------------- fixtures
def low_rank_tensor(shape=(8, 5, 4), ranks=(3, 2, 2), P=60, seed=0, offset=True):
    """Exactly low multilinear rank in the attribute modes, plus a per-coordinate mean shape."""
    rng = np.random.default_rng(seed)
    core = rng.normal(size=(P,) + tuple(ranks))
    U = [rng.normal(size=(d, r)) for d, r in zip(shape, ranks)]
    T = tl.multi_mode_dot(core, [None] + U)
    if offset:
        T = T + 10.0 * rng.normal(size=(P,) + (1,) * len(shape))
    return T


def bilinear_faces(n_id=12, n_expr=6, P=600, ranks=(5, 3), noise=1e-2, seed=1):
    """Bilinear 'faces': a big mean shape plus an identity × expression Tucker term, so every
    identity performs each expression in its own way (copying a mean displacement is wrong)."""
    rng = np.random.default_rng(seed)
    core = rng.normal(size=(P,) + ranks)
    U = rng.normal(size=(n_id, ranks[0]))
    U[:, 0] = 3 + 0.3 * rng.normal(size=n_id)
    V = rng.normal(size=(n_expr, ranks[1]))
    V[:, 0] = 1.0
    T = tl.multi_mode_dot(core, [None, U, V])
    return T + 10 * rng.normal(size=(P, 1, 1)) + noise * rng.normal(size=T.shape)


def hide(T, mask):
    out = T.copy()
    out[:, ~mask] = np.nan
    return out


def rel_err(A, B, cells):
    return np.linalg.norm((A - B)[:, cells]) / np.linalg.norm(B[:, cells])


def make_dataset(T, mask, names=("identity", "expression", "viseme")):
    K = mask.ndim
    P = T.shape[0]
    verts = np.moveaxis(hide(T, mask), 0, K).reshape(mask.shape + (P // 3, 3))
    labels = tuple(tuple(f"{n[:2]}{i}" for i in range(d)) for n, d in zip(names, mask.shape))
    labels = (labels[0], ("neutral",) + labels[1][1:]) + labels[2:]
    return FaceDataset(verts, mask.copy(), tuple(names[:K]), labels,
                       np.array([[0, 1, 2]], dtype=np.int64))


# ------------------------------------------------------------------------- pure pieces
def test_mode_operator_is_the_centred_precision_quadratic():
    rng = np.random.default_rng(0)
    shape = (4, 3, 2)
    Ps = [(lambda M: M @ M.T)(rng.normal(size=(d, d))) for d in shape]
    X = rng.normal(size=(7, int(np.prod(shape))))  # 7 coordinates
    G = X.T @ X
    S = im.mode_scatters(G, shape)
    A = im.joint_operator(Ps, shape)
    assert np.trace(A @ G) == pytest.approx(sum(np.trace(P @ s) for P, s in zip(Ps, S)), rel=1e-12)
    # mode-1 scatter by hand: columns (coordinate, identity, viseme) of 3 expressions, centred
    # on the mean over (identity, viseme) of each (coordinate, expression)
    Xt = X.reshape((7,) + shape)
    V = np.moveaxis(Xt, 2, -1)  # (7, 4, 2, 3): coordinate, identity, viseme, expression
    V = V - V.mean(axis=(1, 2), keepdims=True)
    S1 = np.einsum("piva,pivb->ab", V, V)
    np.testing.assert_allclose(S[1], S1, rtol=1e-12, atol=1e-12)


def test_conditional_mean_minimises_the_gaussian_quadratic():
    rng = np.random.default_rng(1)
    d = 6
    M = rng.normal(size=(d, d))
    C = M @ M.T + 0.1 * np.eye(d)
    mu = rng.normal(size=d)
    x = rng.normal(size=d)
    miss = np.array([False, True, False, True, False, False])
    xm = im.conditional_mean(mu, C, x, miss)
    # gradient of (x - mu)^T C^-1 (x - mu) w.r.t. the missing entries vanishes there
    z = x.copy()
    z[miss] = xm
    grad = (np.linalg.inv(C) @ (z - mu))[miss]
    np.testing.assert_allclose(grad, 0, atol=1e-10)


def test_ppca_fit_is_tipping_bishop_ml():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(5, 400)) * np.array([5, 3, 1, 0.5, 0.2])[:, None]
    Xc = X - X.mean(axis=1, keepdims=True)
    S = Xc @ Xc.T
    full = im.ppca_fit(S, 400)
    np.testing.assert_allclose(full.covariance(), S / 400, rtol=1e-10)
    p2 = im.ppca_fit(S, 400, 2)
    lam = np.sort(np.linalg.eigvalsh(S / 400))[::-1]
    assert p2.noise_var == pytest.approx(lam[2:].mean())  # Eq. (8)
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(p2.covariance()))[::-1][:2], lam[:2])


def test_ppca_incomplete_recovers_a_low_rank_matrix():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(6, 2)) @ rng.normal(size=(2, 300)) + rng.normal(size=(6, 1))
    Xm = X.copy()
    holes = rng.random(X.shape) < 0.15
    holes[:, holes.sum(axis=0) > 3] = False  # a 2-dim subspace needs 3 known entries per column
    Xm[holes] = np.nan
    model, filled, hist = im.ppca_incomplete(Xm, 2, tol=1e-12, max_iter=500)
    assert np.linalg.norm((filled - X)[holes]) / np.linalg.norm(X[holes]) < 1e-4
    # with noise the negative log-likelihood decreases monotonically
    Xn = X + 0.1 * rng.normal(size=X.shape)
    Xn[holes] = np.nan
    _, _, hist = im.ppca_incomplete(Xn, 2, tol=1e-10, max_iter=500)
    assert np.all(np.diff(hist) <= 1e-12 * np.abs(hist[:-1]))
    assert hist[-1] < hist[0]


# -------------------------------------------------------------------- the paper's scheme
@pytest.mark.parametrize("em", ["soft", "hard"])
def test_exact_recovery_of_low_multilinear_rank_data(em):
    T = low_rank_tensor()
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.25, np.random.default_rng(5))
    res = im.impute_tensor(hide(T, ~held), ~held, em=em, tol=1e-12, max_iter=300)
    mean = T.mean(axis=(1, 2, 3), keepdims=True)
    err = np.linalg.norm((res.tensor - T)[:, held]) / np.linalg.norm((T - mean)[:, held])
    assert err < 1e-7
    # known cells untouched
    np.testing.assert_array_equal(res.tensor[:, ~held], T[:, ~held])


@pytest.mark.parametrize("accelerate", [True, False])
@pytest.mark.parametrize("em,ranks,fraction", [("soft", None, 0.3), ("soft", (4, 3), 0.2),
                                               ("hard", (4, 3), 0.2)])
def test_objective_never_rises_and_converges(em, ranks, fraction, accelerate):
    T = bilinear_faces(noise=0.05)
    held = im.random_holdout(np.ones(T.shape[1:], bool), fraction, np.random.default_rng(6))
    res = im.impute_tensor(hide(T, ~held), ~held, em=em, ranks=ranks, accelerate=accelerate,
                           max_iter=400, tol=1e-6)
    h = np.array(res.history)
    assert len(h) == res.iterations + 1
    assert np.all(np.diff(h) <= 1e-12 * np.abs(h[:-1]))
    assert h[-1] < h[0] - 1.0
    assert res.converged


def test_hard_em_shrinks_a_full_covariance_soft_em_does_not():
    """Hard imputation fits its own guesses: with a full covariance it drives eigenvalues to the
    floor; the soft EM (posterior covariance in the M-step) keeps them at the noise level."""
    T = bilinear_faces(noise=0.05)
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.2, np.random.default_rng(6))
    hard = im.impute_tensor(hide(T, ~held), ~held, em="hard", max_iter=400)
    soft = im.impute_tensor(hide(T, ~held), ~held, em="soft", max_iter=400)
    assert np.linalg.eigvalsh(hard.covariances[0]).min() < 1e-6
    assert np.linalg.eigvalsh(soft.covariances[0]).min() > 1e-4


def test_ppca_beats_averaging_when_identities_express_differently():
    T = bilinear_faces()
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.3, np.random.default_rng(7))
    Tin = hide(T, ~held)
    ours = im.impute_tensor(Tin, ~held).tensor
    avg = im.average_impute(Tin, ~held)
    disp = np.linalg.norm((T - T[:, :, :1])[:, held])
    e_ours = np.linalg.norm((ours - T)[:, held]) / disp
    e_avg = np.linalg.norm((avg - T)[:, held]) / disp
    assert e_ours < 0.02  # noise level is ~0.005 of the displacement
    assert e_avg > 0.5


def test_row_weights_change_only_the_covariances():
    T = bilinear_faces(noise=0.05)
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.3, np.random.default_rng(8))
    Tin = hide(T, ~held)
    a = im.impute_tensor(Tin, ~held)
    b = im.impute_tensor(Tin, ~held, row_weights=np.ones(T.shape[0]) * 3.0)
    np.testing.assert_allclose(a.tensor, b.tensor, rtol=1e-8, atol=1e-8)  # uniform scale: same
    w = np.ones(T.shape[0])
    w[: T.shape[0] // 2] = 0.0  # covariances from half of the coordinates only
    c = im.impute_tensor(Tin, ~held, row_weights=w)
    assert np.abs(c.tensor - a.tensor)[:, held].max() > 1e-6
    assert rel_err(c.tensor, T, held) < 0.02  # measured 0.0067 (all rows: 0.0067; averaging 0.33)
    with pytest.raises(ValueError, match="row_weights"):
        im.impute_tensor(Tin, ~held, row_weights=np.ones(3))


# ------------------------------------------------------------------------------ baselines
def test_averaging_is_exact_on_additive_data():
    rng = np.random.default_rng(9)
    P, n_id, n_e, n_v = 30, 6, 4, 3
    T = (rng.normal(size=(P, n_id, 1, 1)) + rng.normal(size=(P, 1, n_e, n_v))
         + 5 * rng.normal(size=(P, 1, 1, 1)))
    mask = ~im.random_holdout(np.ones((n_id, n_e, n_v), bool), 0.3, rng)
    out = im.average_impute(hide(T, mask), mask)
    np.testing.assert_allclose(out, T, atol=1e-10)


def test_averaging_uses_the_neutral_and_the_mean_displacement():
    T = np.zeros((3, 3, 2))
    T[:, 0, :] = [[0, 1], [0, 1], [0, 1]]
    T[:, 1, :] = [[1, 4], [1, 4], [1, 4]]
    T[:, 2, 0] = 10
    mask = np.ones((3, 2), bool)
    mask[2, 1] = False
    out = im.average_impute(hide(T, mask), mask, reference=(0,))
    np.testing.assert_allclose(out[:, 2, 1], 10 + (1 + 3) / 2)


def test_naive_and_tensorly_fill_exact_low_rank_data():
    T = low_rank_tensor(offset=False, shape=(8, 5, 4), ranks=(3, 2, 2))
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.15, np.random.default_rng(10))
    Tin = hide(T, ~held)
    naive, steps = im.naive_impute(Tin, ~held)
    assert steps >= 1
    assert rel_err(naive, T, held) < 1e-6
    pytest.importorskip("tensorly")
    tly = im.tensorly_impute(Tin, ~held, ranks=(3, 2, 2), tol=1e-14, max_iter=500, center=False)
    assert rel_err(tly, T, held) < 1e-9  # measured 4.5e-14: exact data, exact ranks


# -------------------------------------------------------------------------- data sets
def test_impute_dataset_fills_and_records():
    T = bilinear_faces(P=300, n_id=10, n_expr=5)
    mask = np.ones(T.shape[1:], bool)
    mask[2, 3] = mask[5, 1] = False
    ds = make_dataset(T, mask, ("identity", "expression"))
    res = im.impute_dataset(ds)
    assert res.dataset.mask.all()
    np.testing.assert_array_equal(res.imputed, ~mask)
    assert np.isfinite(res.dataset.vertices).all()
    np.testing.assert_array_equal(res.dataset.vertices[mask], ds.vertices[mask])
    info = res.dataset.provenance["imputation"]
    assert info["method"] == "ppca" and info["n_imputed"] == 2
    assert ["id2", "ex3"] in info["cells"]
    filled = np.moveaxis(res.dataset.vertices.reshape(mask.shape + (-1,)), -1, 0)
    assert rel_err(filled, T, ~mask) < 0.01
    Tin = hide(T, mask)
    for method, want in (("average", im.average_impute(Tin, mask)),
                         ("naive", im.naive_impute(Tin, mask)[0])):
        r = im.impute_dataset(ds, method=method)
        assert r.dataset.mask.all() and r.dataset.provenance["imputation"]["method"] == method
        # the data set's cells are the tensor method's, in the right places (measured equal)
        got = np.moveaxis(r.dataset.vertices.reshape(mask.shape + (-1,)), -1, 0)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert rel_err(got, T, ~mask) < 0.005  # naive: measured 0.0015 (averaging: 0.12)
    with pytest.raises(ValueError, match="unknown imputation method"):
        im.impute_dataset(ds, method="magic")


def test_random_holdout_never_empties_a_slice():
    base = np.ones((4, 3, 3), bool)
    for seed in range(5):
        held = im.random_holdout(base, 0.6, seed)
        assert held.sum() == round(0.6 * base.size)
        im.validate_mask(base & ~held, base.shape)  # does not raise
    with pytest.raises(DatasetError, match="cannot hide"):
        im.random_holdout(np.ones((2, 2), bool), 0.9, 0)


# -------------------------------------------------------------------------- bad input
@pytest.fixture
def small_ds():
    T = bilinear_faces(n_id=4, n_expr=3, P=30, ranks=(2, 2))
    return make_dataset(T, np.ones((4, 3), bool), ("identity", "expression"))


def _with_mask(ds, mask):
    verts = ds.vertices.copy()
    verts[~mask] = np.nan
    return FaceDataset(verts, mask, ds.mode_names, ds.labels, ds.faces)


def test_identity_with_no_data_is_named(small_ds):
    mask = np.ones((4, 3), bool)
    mask[2] = False
    with pytest.raises(DatasetError, match=r"identity 'id2' \(mode 0 'identity', index 2\)"):
        im.impute_dataset(_with_mask(small_ds, mask))


def test_expression_with_no_data_is_named(small_ds):
    mask = np.ones((4, 3), bool)
    mask[:, 1] = False
    with pytest.raises(DatasetError, match=r"expression 'ex1' \(mode 1"):
        im.impute_dataset(_with_mask(small_ds, mask), method="average")


def test_all_missing_mask_shape_and_one_identity(small_ds):
    with pytest.raises(DatasetError, match="all 12 cells are missing"):
        im.validate_mask(np.zeros((4, 3), bool), (4, 3))
    with pytest.raises(DatasetError, match=r"mask shape \(3, 3\) does not match"):
        im.validate_mask(np.ones((3, 3), bool), (4, 3))
    with pytest.raises(DatasetError, match=r"mask shape"):
        im.impute_tensor(np.zeros((6, 4, 3)), np.ones((4, 2), bool))
    one = FaceDataset(small_ds.vertices[:1], np.ones((1, 3), bool), small_ds.mode_names,
                      (small_ds.labels[0][:1], small_ds.labels[1]), small_ds.faces)
    with pytest.raises(DatasetError, match="at least 2 identitys|at least 2 identit"):
        im.impute_dataset(one)


def test_nan_in_a_known_cell_is_rejected(small_ds):
    verts = small_ds.vertices.copy()
    verts[1, 1, 0, 0] = np.nan
    bad = FaceDataset(verts, small_ds.mask, small_ds.mode_names, small_ds.labels, small_ds.faces)
    with pytest.raises(DatasetError, match="NaN"):
        im.impute_dataset(bad)



@pytest.mark.parametrize("bad, said", [
    (np.ones((6, 4, 3)) + 1j, "real numbers, got complex"),
    (np.full((6, 4, 3), "x"), "real numbers, got text"),
    (np.zeros((0, 4, 3)), r"\(0, 4, 3\) has no vertex coordinates"),
])
def test_complex_text_or_empty_tensor_is_refused(bad, said):
    """A complex tensor was imputed from its real part (a ComplexWarning only), text failed
    with numpy's own message, a tensor of no coordinates with "cannot reshape"; the shared
    check (check_tensor) serves every method."""
    from facetransfer.errors import ShapeError

    mask = np.ones((4, 3), bool)
    mask[1, 2] = False
    for method in (im.impute_tensor, im.average_impute, im.naive_impute):
        with pytest.raises(ShapeError, match=said):
            method(bad, mask)

def test_too_many_cells_is_a_clear_error():
    mask = np.ones((61, 50), bool)
    mask[0, 0] = False
    with pytest.raises(DatasetError, match="at most 3000 cells"):
        im.impute_tensor(np.zeros((3, 61, 50)), mask)


def test_bad_options():
    T = bilinear_faces(n_id=4, n_expr=3, P=30, ranks=(2, 2))
    mask = np.ones((4, 3), bool)
    mask[0, 1] = False
    with pytest.raises(ValueError, match="PPCA rank 9"):
        im.impute_tensor(T, mask, ranks=(9, 2))
    with pytest.raises(ValueError, match="em must be"):
        im.impute_tensor(T, mask, em="medium")
    with pytest.raises(ValueError, match="fraction"):
        im.random_holdout(mask, 1.5, 0)


# ------------------------------------------------------------------------- face regions
def test_region_memberships_partition_of_unity():
    rng = np.random.default_rng(11)
    V = rng.normal(size=(200, 3))
    lm = rng.choice(200, 68, replace=False)
    for regions in ("mouth", 1, 5):
        M = im.region_memberships(V, regions=regions, landmarks=lm)
        assert M.shape[1] == 200 and (M >= 0).all()
        np.testing.assert_allclose(M.sum(axis=0), 1.0)
    mouth = im.region_memberships(V, regions="mouth", landmarks=lm)
    centre = V[lm[48:68]].mean(axis=0)
    near = np.argmin(np.linalg.norm(V - centre, axis=1))
    far = np.argmax(np.linalg.norm(V - centre, axis=1))
    assert mouth[0].argmax() == near and mouth[0, far] < 0.5 * mouth[0, near]
    with pytest.raises(DatasetError, match="landmark"):
        im.region_memberships(V, regions="mouth")
    with pytest.raises(ValueError, match="regions must be"):
        im.region_memberships(V, regions="nose", landmarks=lm)


def test_regions_blend_and_one_region_is_the_plain_scheme():
    T = bilinear_faces(noise=0.05)
    held = im.random_holdout(np.ones(T.shape[1:], bool), 0.2, np.random.default_rng(12))
    Tin = hide(T, ~held)
    n = T.shape[0] // 3
    plain = im.impute_tensor(Tin, ~held)
    one = im.impute_tensor_regions(Tin, ~held, np.ones((1, n)))
    np.testing.assert_allclose(one.tensor, plain.tensor, rtol=1e-9, atol=1e-9)
    M = im.region_memberships(np.random.default_rng(0).normal(size=(n, 3)), regions=3)
    three = im.impute_tensor_regions(Tin, ~held, M)
    h = np.array(three.history)
    assert np.all(np.diff(h) <= 1e-12 * np.abs(h[:-1]))
    np.testing.assert_array_equal(three.tensor[:, ~held], T[:, ~held])
    assert rel_err(three.tensor, T, held) < 0.015  # measured 0.0061 (one region: 0.0061)
    with pytest.raises(ValueError, match="memberships"):
        im.impute_tensor_regions(Tin, ~held, np.full((2, n), 0.3))


def test_impute_dataset_with_mouth_regions():
    T = bilinear_faces(P=600, n_id=10, n_expr=5)
    mask = np.ones(T.shape[1:], bool)
    mask[2, 3] = mask[5, 1] = False
    ds = make_dataset(T, mask, ("identity", "expression"))
    with pytest.raises(DatasetError, match="landmark"):
        im.impute_dataset(ds, regions="mouth")
    ds = FaceDataset(ds.vertices, ds.mask, ds.mode_names, ds.labels, ds.faces,
                     landmarks=np.arange(68, dtype=np.int64))
    res = im.impute_dataset(ds, regions="mouth")
    assert res.dataset.provenance["imputation"]["regions"] == "mouth"
    filled = np.moveaxis(res.dataset.vertices.reshape(mask.shape + (-1,)), -1, 0)
    assert rel_err(filled, T, ~mask) < 0.01
    with pytest.raises(ValueError, match="'ppca' only"):
        im.impute_dataset(ds, method="average", regions="mouth")


# --------------------------------------------------------------------- real face meshes
def test_additive_ict_faces_are_recovered(quick_ict_dataset):
    """ICT-FaceKit faces with expressions added identically to every identity (the additive
    data set of conftest): both the paper's scheme and averaging are exact on it."""
    ds = quick_ict_dataset
    held = im.random_holdout(ds.mask, 0.3, np.random.default_rng(13))
    verts = ds.vertices.copy()
    verts[held] = np.nan
    inc = FaceDataset(verts, ds.mask & ~held, ds.mode_names, ds.labels, ds.faces,
                      landmarks=ds.landmarks)
    truth = ds.vertices[held]
    disp = np.linalg.norm(truth - ds.vertices[:, :1][np.nonzero(held)[0]])
    for method in ("ppca", "average"):
        res = im.impute_dataset(inc, method=method)
        err = np.linalg.norm(res.dataset.vertices[held] - truth) / disp
        assert err < 1e-6, method


def test_an_init_of_another_shape_is_named():
    """An init of the wrong size failed in numpy's reshape ("cannot reshape array of size 9"),
    and one of the right size but another layout (P, d_1 d_2) was read as if it were right."""
    from facetransfer.errors import ShapeError

    T = low_rank_tensor(shape=(6, 5), ranks=(2, 2), P=30)
    mask = np.ones((6, 5), bool)
    mask[0, 1] = mask[2, 3] = False
    with pytest.raises(ShapeError, match=r"shape \(30, 6, 5\), got \(3, 3\)"):
        im.impute_tensor(hide(T, mask), mask, init=np.zeros((3, 3)))
    with pytest.raises(ShapeError, match=r"shape \(30, 6, 5\), got \(30, 30\)"):
        im.impute_tensor(hide(T, mask), mask, init=T.reshape(30, 30))
    done = im.impute_tensor(hide(T, mask), mask, init=T, tol=1e-12, max_iter=300)
    np.testing.assert_allclose(done.tensor, T, atol=1e-6)


def test_evaluation_refuses_a_method_or_fraction_given_twice(small_ds):
    """evaluate_imputation(ds, [0.1, 0.1]) or methods ("average", "average") ran each twice
    and reported every row twice."""
    with pytest.raises(ValueError, match="missing fractions gives 0.1 twice"):
        im.evaluate_imputation(small_ds, [0.1, 0.1], trials=1, methods=("average",))
    with pytest.raises(ValueError, match="methods gives 'average' twice"):
        im.evaluate_imputation(small_ds, [0.1], trials=1, methods=("average", "average"))


def test_iteration_options_and_ranks_are_checked(small_ds):
    """max_iter=-1 or tol=NaN ran (no iteration; never stopping early) without a word;
    tensorly_impute's ranks [0, 0] failed with numpy's "cannot reshape array of size 0";
    all-zero row weights were said as a wrong shape (the shape given was right)."""
    T = small_ds.vertices.reshape(small_ds.vertices.shape[:2] + (-1,))
    T = np.moveaxis(T, -1, 0)
    mask = np.ones(T.shape[1:], bool)
    mask[1, 1] = False
    with pytest.raises(ValueError, match=r"impute_tensor: max_iter must be an integer >= 0, "
                                         r"got -1"):
        im.impute_tensor(T, mask, max_iter=-1)
    with pytest.raises(ValueError, match=r"impute_tensor: tol must be a number \(not NaN\)"):
        im.impute_tensor(T, mask, tol=float("nan"))
    with pytest.raises(ValueError, match=r"hooi: max_iter must be an integer >= 0, got 2.5"):
        tl.hooi(T, max_iter=2.5)
    with pytest.raises(ValueError, match=r"row_weights must be finite, non-negative and not all "
                                         r"zero, got 0 negative, 0 NaN or infinite, sum 0"):
        im.impute_tensor(T, mask, row_weights=np.zeros(T.shape[0]))
    pytest.importorskip("tensorly")   # last: inside pytest.raises its skip skipped the rest
    with pytest.raises(ValueError, match=r"tensorly_impute: ranks must be 2 integers, each from "
                                         r"1 to its mode's size"):
        im.tensorly_impute(T, mask, ranks=[0, 0])


def test_complex_row_weights_and_init_are_refused_naming_them(small_ds):
    """impute_tensor took complex row_weights and init as their real parts (a ComplexWarning
    only), as the tensor itself did before ``arrays.real_array``; impute_missing's
    vertex_weights the same."""
    from facetransfer.errors import ShapeError

    T = low_rank_tensor(shape=(6, 5), ranks=(2, 2), P=30)
    mask = np.ones((6, 5), bool)
    mask[0, 1] = False
    with pytest.raises(ShapeError, match=r"row_weights must be real numbers, got complex"):
        im.impute_tensor(hide(T, mask), mask, row_weights=np.ones(30) + 1j)
    with pytest.raises(ShapeError, match=r"init must be real numbers, got complex"):
        im.impute_tensor(hide(T, mask), mask, init=T + 1j)
    held = np.ones((4, 3), bool)
    held[1, 2] = False
    with pytest.raises(ShapeError, match=r"vertex_weights must be real numbers, got complex"):
        im.impute_dataset(_with_mask(small_ds, held),
                          vertex_weights=np.ones(small_ds.n_vertices) + 1j)


def test_an_empty_slice_of_an_unnamed_mask_is_said_plainly():
    """Without mode names or labels the slice was said "mode 0 '0' (mode 0 'mode 0', index 0)
    has no known cell"."""
    mask = np.ones((4, 3), bool)
    mask[:, 2] = False
    with pytest.raises(DatasetError, match=r"^mode 1 index 2 has no known cell \(mask \(4, 3\)\): "
                                           r"a slice with no data at all cannot be imputed$"):
        im.validate_mask(mask, (4, 3))
