"""The baselines §4.4's imputation is measured against (Vlasic et al. 2005, §4.4 "Evaluation").

Baselines
---------
* ``average``: Blanz et al. [2003] as generalised in §4.4 "Evaluation": the mean displacement of the
  missing cell from the reference (neutral) cell over the identities that have both, added to this
  identity's reference face.
* ``naive``: §4.4's naive imputation — a complete sub-tensor, a smaller model, predict, augment,
  repeat.
* ``tensorly``: ``tensorly``'s masked Tucker (HOOI with EM imputation), the external peer.

References
----------
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4.
Blanz, Basso, Poggio, Vetter 2003, "Reanimating faces in images and video", Eurographics.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import tensor as tl
from ..arrays import check_iterations
from .cells import Progress, check_tensor, validate_mask

__all__ = ["reference_indices", "average_impute", "naive_impute", "tensorly_impute"]


def reference_indices(mode_names: Sequence[str] | None, labels: Sequence[Sequence[str]] | None,
                      shape: Sequence[int]) -> tuple[int, ...]:
    """Index of the reference ("neutral") item of every non-identity mode.

    The label ``neutral`` (any case) if present, else index 0 (data sets list neutral first).
    """
    out = []
    for k in range(1, len(shape)):
        idx = 0
        if labels is not None:
            low = [str(l).lower() for l in labels[k]]
            for name in ("neutral", "rest", "m"):
                if name in low:
                    idx = low.index(name)
                    break
        out.append(idx)
    return tuple(out)


def average_impute(tensor: np.ndarray, mask: np.ndarray, *, reference: Sequence[int] | None = None,
                   mode_names=None, labels=None) -> np.ndarray:
    """Averaging baseline (Blanz et al. 2003 as generalised in §4.4 "Evaluation").

    A missing cell ``(i, c)`` is predicted as identity ``i``'s reference face ``T[:, i, r]`` plus
    the     mean displacement ``T[:, i', c] - T[:, i', r]`` over identities ``i'`` that have both cells.
    ``r`` is the neutral cell (``reference``, all non-identity modes at their neutral item); if
    identity ``i`` lacks it, the nearest known cell of ``i`` (fewest modes differing from the
    neutral, then most identities sharing it with ``c``). If no other identity has ``c`` with any of
    ``i``'s known cells, the reference face itself is used.

    Parameters
    ----------
    tensor : (P, d_1, ..., d_K) array, identity mode first among the attribute modes
    mask : (d_1, ..., d_K) bool
    reference : sequence of K-1 ints, optional (default :func:`reference_indices`)

    Returns
    -------
    (P, d_1, ..., d_K) array, filled
    """
    mask = validate_mask(mask, np.shape(tensor)[1:], mode_names=mode_names, labels=labels)
    T = check_tensor(tensor, mask)
    shape = mask.shape
    ref = (tuple(reference) if reference is not None
           else reference_indices(mode_names, labels, shape))
    out = T.copy()
    cells = list(np.ndindex(*shape[1:]))
    for idx in zip(*np.nonzero(~mask)):
        i, c = int(idx[0]), tuple(int(v) for v in idx[1:])
        known_i = [r for r in cells if mask[(i,) + r]]
        col_c = mask[(slice(None),) + c]

        def key(r):
            dist = sum(a != b for a, b in zip(r, ref))
            share = int(np.sum(col_c & mask[(slice(None),) + r]))
            return (r != ref, dist, -share)

        pred = None
        for r in sorted(known_i, key=key):
            donors = np.nonzero(col_c & mask[(slice(None),) + r])[0]
            donors = donors[donors != i]
            if donors.size:
                disp = (T[(slice(None), donors) + c] - T[(slice(None), donors) + r]).mean(axis=1)
                pred = T[(slice(None), i) + r] + disp
                break
        if pred is None:
            r = sorted(known_i, key=key)[0]
            pred = T[(slice(None), i) + r]
        out[(slice(None), i) + c] = pred
    return out


def _compress(T: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal basis ``Q`` (P, r) of the known cells' span and the tensor in it, (r, d...).

    Every method here is equivariant under an orthonormal change of basis of the vertex mode and
    predicts missing cells inside the span of the known ones, so working on ``Q^T T`` is exact.
    """
    P = T.shape[0]
    Y = T.reshape(P, -1)
    Yk = Y[:, mask.ravel()]
    Q, _ = np.linalg.qr(Yk)
    Z = np.zeros((Q.shape[1], Y.shape[1]))
    Z[:, mask.ravel()] = Q.T @ Yk
    return Q, Z.reshape((Q.shape[1],) + mask.shape), Y


def naive_impute(tensor: np.ndarray, mask: np.ndarray, *, max_rank: int | None = None,
                 mode_names=None, labels=None, progress: Progress | None = None
                 ) -> tuple[np.ndarray, int]:
    """Naive imputation (§4.4): complete sub-tensor → smaller model → predict → augment → repeat.

    1. The complete sub-tensor: starting from all cells, repeatedly drop the slice (mode, index)
       with the most missing cells (ties: larger missing fraction, lower mode, lower index) until
       no cell is missing.
    2. Repeatedly: build a model (N-mode SVD, vertex mode unfactored, Eq. (4); ranks
       ``min(size, max_rank)``) of the current complete sub-tensor; among the slices not yet in it,
       take the one with the most known cells inside the sub-tensor's other indices (ties: lower
       mode, lower index); fit that slice's attribute weights to its known cells by least squares
       through the model (Eq. (9)); predict its missing cells; add the slice.

    The result depends on this order, as the paper notes.

    Returns
    -------
    filled : (P, d_1, ..., d_K) array
    steps : int, number of augmentations
    """
    mask = validate_mask(mask, np.shape(tensor)[1:], mode_names=mode_names, labels=labels)
    T = check_tensor(tensor, mask)
    if mask.all():
        return T.copy(), 0
    shape = mask.shape
    Q, Z, Y = _compress(T, mask)
    Z = Z.copy()
    known = mask.copy()
    sel = _complete_subtensor(known)  # 1.
    total = sum(d - len(s) for d, s in zip(shape, sel))
    steps = 0
    while any(len(s) < d for s, d in zip(sel, shape)):  # 2.
        k, a = _augment(Z, known, sel, max_rank)
        sel[k] = sorted(sel[k] + [a])
        steps += 1
        if progress is not None:
            progress(steps, total)
    # cells outside every added slice were filled when their last slice was added
    out = Y.copy()
    miss = ~mask.ravel()
    out[:, miss] = Q @ Z.reshape(Z.shape[0], -1)[:, miss]
    return out.reshape(T.shape), steps


def _sub(arr: np.ndarray, sel: Sequence[Sequence[int]]) -> np.ndarray:
    """The sub-array at the index lists ``sel`` of the cell modes (a leading vertex mode kept)."""
    if arr.ndim == len(sel):
        return arr[np.ix_(*sel)]
    return arr[np.ix_(range(arr.shape[0]), *sel)]


def _with_slice(sel: list[list[int]], k: int, a: int) -> list[list[int]]:
    """``sel`` with mode ``k`` narrowed to the single index ``a``."""
    s = list(sel)
    s[k] = [a]
    return s


def _complete_subtensor(known: np.ndarray) -> list[list[int]]:
    """Step 1 of :func:`naive_impute`: index lists of a complete sub-tensor of ``known``.

    Repeatedly drops the slice (mode, index) with the most missing cells (ties: larger missing
    fraction, lower mode, lower index) until no cell is missing.
    """
    sel = [list(range(d)) for d in known.shape]
    while not _sub(known, sel).all():
        best = None
        for k in range(known.ndim):
            if len(sel[k]) <= 1:
                continue
            for a in sel[k]:
                block = _sub(known, _with_slice(sel, k, a))
                n_miss = int((~block).sum())
                key = (n_miss, n_miss / block.size, -k, -a)
                if best is None or key > best[0]:
                    best = (key, k, a)
        if best is None:  # a single cell left: it must be known
            break
        _, k, a = best
        sel[k] = [x for x in sel[k] if x != a]
    return sel


def _next_slice(known: np.ndarray, sel: list[list[int]]) -> tuple[int, int]:
    """Step 2b: the slice (mode, index) outside ``sel`` with the most known cells inside the
    sub-tensor's other indices (ties: lower mode, lower index)."""
    best = None
    for k, d in enumerate(known.shape):
        for a in range(d):
            if a in sel[k]:
                continue
            n_known = int(_sub(known, _with_slice(sel, k, a)).sum())
            key = (n_known, -k, -a)
            if best is None or key > best[0]:
                best = (key, k, a)
    return best[1], best[2]


def _augment(Z: np.ndarray, known: np.ndarray, sel: list[list[int]], max_rank: int | None
             ) -> tuple[int, int]:
    """Step 2 once: model the complete sub-tensor, predict the next slice, write it into ``Z``.

    ``Z`` (r, d_1..d_K) and ``known`` (d_1..d_K) are updated in place; returns the slice
    ``(mode, index)`` added.
    """
    # 2a. the model of the complete sub-tensor (vertex mode unfactored, Eq. (4))
    rk = [None] + [len(s) if max_rank is None else min(len(s), max_rank) for s in sel]
    dec = tl.nmode_svd(_sub(Z, sel), rk, skip=(0,))
    k, a = _next_slice(known, sel)  # 2b.
    s = _with_slice(sel, k, a)
    pred = _slice_prediction(dec, _sub(Z, s), _sub(known, s), k)
    # write the predictions into the missing cells of the slice
    full_pred = np.moveaxis(pred[..., None], -1, k + 1)
    cur = np.where(_sub(known, s)[None], _sub(Z, s), full_pred)
    Z[np.ix_(range(Z.shape[0]), *s)] = cur
    known[np.ix_(*s)] = True
    return k, a


def _slice_prediction(dec, block: np.ndarray, block_known: np.ndarray, k: int) -> np.ndarray:
    """Fit a slice's mode-``k`` weights to its known cells through the model (Eq. (9)), predict.

    Parameters
    ----------
    dec : the sub-tensor's N-mode SVD (``core``, ``factors``)
    block : (r0, ...) the slice, mode ``k`` of size 1
    block_known : (...) bool, its known cells
    k : int, the slice's attribute mode (0-based)

    Returns
    -------
    (r0, o...) the predicted slice, other modes at the sub-tensor's rows
    """
    K = block_known.ndim
    # basis of mode k with the other modes at their sub-tensor rows (Eq. (9))
    others = [None] + [None if m == k else dec.factors[m + 1] for m in range(K)]
    Bas = tl.multi_mode_dot(dec.core, others)  # (r0, ..., r_k, ...) with other modes expanded
    Bas = np.moveaxis(Bas, k + 1, -1)  # (r0, o..., r_k)
    kn = np.moveaxis(block_known, k, -1)[..., 0]  # other-mode cells of the slice
    target = np.moveaxis(block, k + 1, -1)[..., 0]  # (r0, o...)
    A = Bas[:, kn, :].reshape(-1, Bas.shape[-1])
    b = target[:, kn].reshape(-1)
    if A.shape[0]:
        w = np.linalg.lstsq(A, b, rcond=None)[0]
    else:  # no known cell in the sub-tensor's range: the mean attribute vector
        w = dec.factors[k + 1].mean(axis=0)
    return Bas @ w  # (r0, o...)


def tensorly_impute(tensor: np.ndarray, mask: np.ndarray, *, ranks: Sequence[int] | None = None,
                    max_iter: int = 100, tol: float = 1e-6, rng=None, center: bool = True,
                    mode_names=None, labels=None) -> np.ndarray:
    """External peer: ``tensorly``'s masked Tucker (HOOI with EM imputation), attribute modes only.

    ``tensorly.decomposition.partial_tucker(..., mask=...)`` over modes 1..K (the vertex mode is
    left unfactored, as in Eq. (4)); missing cells get the Tucker reconstruction. The vertex mode
    is first compressed to the span of the known cells (exact, see :func:`_compress`) and centred
    on the known cells' mean face (Tucker has no mean term; without it the peer does far worse).

    Parameters
    ----------
    ranks : K ints, optional
        Tucker ranks of the attribute modes (default ``ceil(d_k / 2)``, the best of a sweep on
        ict-trilinear: ``d_k - 1`` and ``ceil(d_k / 4)`` did worse).
    """
    try:
        from tensorly.decomposition import partial_tucker  # benchmark/test dependency only
    except ImportError:
        raise ValueError("method 'tensorly' needs the tensorly package (pip install tensorly; "
                         "it is in the 'bench' and 'test' extras)") from None

    mask = validate_mask(mask, np.shape(tensor)[1:], mode_names=mode_names, labels=labels)
    T = check_tensor(tensor, mask)
    if mask.all():
        return T.copy()
    shape = mask.shape
    K = len(shape)
    rk = list(ranks) if ranks is not None else [max(1, -(-d // 2)) for d in shape]
    if len(rk) != K or not all(isinstance(r, (int, np.integer)) and 1 <= r <= d
                               for r, d in zip(rk, shape)):
        raise ValueError(f"tensorly_impute: ranks must be {K} integers, each from 1 to its "
                         f"mode's size {tuple(shape)}, got {tuple(rk)}")
    check_iterations(max_iter, tol, "tensorly_impute")
    Q, Z, Y = _compress(T, mask)
    # centre on the known cells' mean face (the usual preprocessing; Tucker has no mean term)
    mean = Z.reshape(Z.shape[0], -1)[:, mask.ravel()].mean(axis=1)
    mean = mean.reshape((-1,) + (1,) * K) * float(center)
    Z = np.where(mask[None], Z - mean, 0.0)
    full_mask = np.broadcast_to(mask, Z.shape).astype(np.float64)
    seed = None if rng is None else int(np.random.default_rng(rng).integers(2 ** 31))
    (core, factors), _ = partial_tucker(Z, rank=rk, modes=list(range(1, K + 1)),
                                        n_iter_max=max_iter, tol=tol, mask=full_mask,
                                        random_state=seed)
    rec = tl.multi_mode_dot(core, [None] + list(factors)) + mean
    out = Y.copy()
    miss = ~mask.ravel()
    out[:, miss] = Q @ rec.reshape(rec.shape[0], -1)[:, miss]
    return out.reshape(T.shape)
