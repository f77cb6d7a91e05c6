"""The multilinear face model (Vlasic et al. 2005, §4.3): Eq. (4), (5) and (9), and its file format.

A data tensor of corresponded meshes ``T`` (vertex mode first, Fig. 3) is decomposed without
factoring the vertex mode (Eq. (4))::

    T ≈ M ×_2 U_2 ×_3 U_3 ... ×_N U_N

``M`` is the *model*: ``(3 n_vertices, r_2, ..., r_N)``. Row ``i`` of ``U_k`` is the attribute vector
of training item ``i`` in mode ``k``, so contracting ``M`` with one row per mode reproduces one
training face, and any weights give a new face (Eq. (5)). Fixing all modes but one turns the model
into a linear basis for that mode (Eq. (9)), which the tracker solves for.

Mode names are the attribute modes only (``("identity", "expression"[, "viseme"])``); the vertex
mode is implicit. Vertex coordinates are vertex-major: row ``3 v + c`` of ``M`` is coordinate ``c`` of
vertex ``v``.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
import os
import threading
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from . import tensor as tl
from .datasets.base import FaceDataset
from .arrays import real_array
from .errors import DatasetError, ModelFileError, ShapeError
from .io.atomic import atomic_path, check_before_commit
from .io.verified import remember_verified, was_verified

log = logging.getLogger(__name__)

#: content_hash of each model object, computed once (a model's arrays are never changed in place).
_HASHES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()

#: per model object, the core contracted with the first mode's weights of recent single-frame
#: calls, ``{weights bytes: (3n, r_2, ...) core}`` (at most :data:`_FIRST_MODE_KEPT`, oldest
#: dropped first): the frames of a clip share one identity (a transfer interleaves two), so
#: :meth:`MultilinearModel.synthesize` of one frame then reads a core r_1 times smaller.
_FIRST_MODE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_FIRST_MODE_KEPT = 3

#: the model file each model object was loaded from or saved to, with that file's identity then
#: (:func:`model_file`).
_FILES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_FIRST_MODE_LOCK = threading.Lock()   # the render calls synthesize from several threads

#: How far given weights may reach (:meth:`MultilinearModel.check_reach`): their norm at most
#: this many times the longest training weights' of their mode. An identity of 1e300 made a
#: face no triangle of which had an area, 1e308 one of NaN, each failing later, naming neither
#: the weights nor where they were given. A face 3 times as far as a training one (a
#: caricature) is a researcher's choice: the bound leaves it room.
WEIGHT_REACH = 1000.0

#: Version of the model file format written by :meth:`MultilinearModel.save`.
FORMAT_VERSION = 1
_MAGIC = "facetransfer-model"

Weights = Mapping[str, np.ndarray] | Sequence[np.ndarray]


@dataclass(frozen=True, eq=False)
class MultilinearModel:
    """A multilinear face model (Eq. (4)) with everything needed to use it.

    Attributes
    ----------
    core : (3 n_vertices, r_1, ..., r_K) float64
        The model tensor ``M`` (vertex mode unfactored).
    factors : tuple of (d_k, r_k) float64
        Per-mode factor matrices ``Ǔ_k``; row ``i`` is the attribute vector of training item ``i``.
    mode_names : tuple of str
    labels : tuple of tuple of str
        Training labels per mode (``len(labels[k]) == d_k``).
    faces : (n_faces, 3) int64
    uvs : (n_vertices, 2) float64 or None
    landmarks : (68,) int64 or None
        iBUG-68 landmark vertices (indices into this model's vertices).
    vertex_subset : (n_vertices,) int64 or None
        Indices of the model's vertices in the source template.
    eigenvalues : tuple of (d_k,) float64
        Mode-k eigenvalues of the data (squared mode singular values) for explained variance.
    imputed : (d_1, ..., d_K) bool or None
        Cells of the training tensor that were imputed (§4.4) rather than measured.
    provenance : dict
        Data set, recipe, seed, ranks, refinement and errors: what it was built from.
    """

    core: np.ndarray
    factors: tuple[np.ndarray, ...]
    mode_names: tuple[str, ...]
    labels: tuple[tuple[str, ...], ...]
    faces: np.ndarray
    uvs: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    vertex_subset: np.ndarray | None = None
    eigenvalues: tuple[np.ndarray, ...] = ()
    imputed: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        K = len(self.mode_names)
        if self.core.ndim != K + 1 or self.core.shape[0] % 3:
            raise ShapeError(f"model core must be (3 n_vertices, r_1..r_{K}), got {self.core.shape}")
        if len(self.factors) != K or len(self.labels) != K:
            raise ShapeError(f"{K} modes need {K} factors and label lists, got "
                             f"{len(self.factors)} and {len(self.labels)}")
        for k, (U, lab) in enumerate(zip(self.factors, self.labels)):
            if U.ndim != 2 or U.shape[1] != self.core.shape[k + 1] or U.shape[0] != len(lab):
                raise ShapeError(f"factor of mode {self.mode_names[k]!r} has shape {U.shape}, "
                                 f"expected ({len(lab)}, {self.core.shape[k + 1]})")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ShapeError(f"faces must be (n_faces, 3), got {self.faces.shape}")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= self.n_vertices):
            raise ShapeError(f"faces index outside 0..{self.n_vertices - 1}")
        if self.landmarks is not None and (self.landmarks.min() < 0
                                           or self.landmarks.max() >= self.n_vertices):
            raise ShapeError(f"landmarks index outside 0..{self.n_vertices - 1}")

    # ----------------------------------------------------------------- basic properties
    @property
    def n_vertices(self) -> int:
        return self.core.shape[0] // 3

    @property
    def n_modes(self) -> int:
        return len(self.mode_names)

    @property
    def ranks(self) -> tuple[int, ...]:
        return tuple(self.core.shape[1:])

    @property
    def shape(self) -> tuple[int, ...]:
        """Training cells per mode ``(d_1, ..., d_K)``."""
        return tuple(U.shape[0] for U in self.factors)

    @property
    def identity_mode(self) -> str:
        """The name of the mode that holds the person: ``"identity"``, or the first mode of a
        model without one (the first mode of the data sets' Cartesian products)."""
        return "identity" if "identity" in self.mode_names else self.mode_names[0]

    def mode_index(self, mode: str | int) -> int:
        """Index of a mode given by name or index."""
        if isinstance(mode, (int, np.integer)):
            if not 0 <= mode < self.n_modes:
                raise ValueError(f"mode {mode} out of range; the model has modes {self.mode_names}")
            return int(mode)
        try:
            return self.mode_names.index(mode)
        except ValueError:
            raise ValueError(f"unknown mode {mode!r}; the model has modes "
                             f"{', '.join(self.mode_names)}") from None

    def label_index(self, mode: str | int, label: str) -> int:
        k = self.mode_index(mode)
        try:
            return self.labels[k].index(str(label))
        except ValueError:
            raise ValueError(f"unknown {self.mode_names[k]} {label!r}; known: "
                             f"{', '.join(self.labels[k])}") from None

    def training_weights(self, mode: str | int, label: str) -> np.ndarray:
        """Row of mode ``mode``'s factor for a training label, shape (r,) (Eq. (5) weights)."""
        k = self.mode_index(mode)
        return self.factors[k][self.label_index(k, label)].copy()

    def weight_mean(self, mode: str | int) -> np.ndarray:
        """Mean of the training attribute vectors of a mode, shape (r,)."""
        return self.factors[self.mode_index(mode)].mean(axis=0)

    def check_reach(self, mode: str | int, weights, what: str = "weights") -> np.ndarray:
        """``weights`` of ``mode`` (..., r) as float64, refused where a row's norm is more than
        :data:`WEIGHT_REACH` times the longest training row's (or NaN): for weights a user
        gives (``--weights``, a performance spec), not in :meth:`synthesize`'s inner loops.

        Raises
        ------
        ValueError
            Saying ``what`` (e.g. ``"--weights"``), the mode, the norm and the bound.
        """
        k = self.mode_index(mode)
        w = np.asarray(weights, dtype=np.float64)
        longest = float(np.linalg.norm(self.factors[k], axis=1).max())
        norm = float(np.max(np.hypot.reduce(w, axis=-1), initial=0.0))   # 1e300: no overflow
        if not norm <= WEIGHT_REACH * longest:
            raise ValueError(f"{what} of mode {self.mode_names[k]!r} reach {norm:.3g} (their "
                             f"norm), more than {WEIGHT_REACH:g} times the longest training "
                             f"weights' ({longest:.3g}): a face that far collapses or overflows")
        return w

    def weight_cov(self, mode: str | int) -> np.ndarray:
        """Covariance of the training attribute vectors of a mode, shape (r, r).

        With fewer training items than the rank the covariance is singular; a small ridge
        (1e-6 of its trace / r) keeps it invertible for use as a prior.
        """
        U = self.factors[self.mode_index(mode)]
        C = np.cov(U, rowvar=False, bias=True) if U.shape[0] > 1 else np.zeros((U.shape[1],) * 2)
        C = np.atleast_2d(C)
        ridge = 1e-6 * max(np.trace(C) / C.shape[0], 1e-12)
        return C + ridge * np.eye(C.shape[0])

    def default_weights(self) -> dict[str, np.ndarray]:
        """Mean training weights of every mode (the "average face")."""
        return {name: self.weight_mean(name) for name in self.mode_names}

    def like(self, **labels: str) -> dict[str, np.ndarray]:
        """Weights taking each named mode's training row by label, the others at their mean.

        ``model.synthesize(model.like(identity="id03", expression="smile"))`` reproduces that
        training mesh exactly when the model is not truncated.
        """
        w = self.default_weights()
        for mode, lab in labels.items():
            w[self.mode_names[self.mode_index(mode)]] = self.training_weights(mode, lab)
        return w

    # ----------------------------------------------------------------- Eq. (5) and (9)
    def _weights_list(self, weights: Weights) -> list[np.ndarray]:
        if isinstance(weights, Mapping):
            unknown = set(weights) - set(self.mode_names)
            if unknown:
                raise ValueError(f"unknown mode(s) {sorted(unknown)}; the model has modes "
                                 f"{', '.join(self.mode_names)}")
            missing = [n for n in self.mode_names if n not in weights]
            if missing:
                raise ValueError(f"weights missing for mode(s) {missing}")
            ws = [weights[n] for n in self.mode_names]
        else:
            ws = list(weights)
            if len(ws) != self.n_modes:
                raise ValueError(f"{len(ws)} weight vectors for {self.n_modes} modes")
        # real and finite: before, NaN or inf gave a NaN face (a RuntimeWarning only), complex
        # weights their real part, text numpy's message naming no mode
        ws = [real_array(w, f"weights of mode {n!r}", finite=True)
              for n, w in zip(self.mode_names, ws)]
        for name, w, r in zip(self.mode_names, ws, self.ranks):
            if w.ndim == 0 or w.shape[-1] != r:
                raise ShapeError(f"weights of mode {name!r} must end in {r}, got shape {w.shape}")
        return ws

    def _batch_shape(self, ws: list[np.ndarray]) -> tuple[int, ...]:
        """The leading (batch) dimensions the modes' weights broadcast to; ShapeError naming
        each mode's shape where they do not (numpy's own error names neither)."""
        try:
            return np.broadcast_shapes(*[w.shape[:-1] for w in ws])
        except ValueError:
            shapes = ", ".join(f"{n} {w.shape}" for n, w in zip(self.mode_names, ws))
            raise ShapeError(f"the weights' leading (batch) dimensions do not broadcast: "
                             f"{shapes}") from None

    def synthesize(self, weights: Weights, *, vertices: np.ndarray | None = None) -> np.ndarray:
        """Faces from attribute weights, Eq. (5): ``f = M ×_2 w_2ᵀ ×_3 w_3ᵀ ... ×_N w_Nᵀ``.

        Parameters
        ----------
        weights : mapping mode name -> (..., r_k) array, or a sequence in mode order
            Leading (batch) dimensions broadcast against each other; a batch of no rows gives
            no faces. Real and finite (NaN, infinite or complex weights raise ShapeError
            naming the mode).
        vertices : (m,) int array, optional
            Only synthesize these vertices.

        Returns
        -------
        (..., n_vertices or m, 3) float64
        """
        ws = self._weights_list(weights)
        batch = self._batch_shape(ws)
        if vertices is not None and np.size(vertices) == 0:   # an empty selection
            return np.zeros(batch + (0, 3))
        if math.prod(batch) == 0:     # no faces asked for (e.g. a clip of no frames)
            n = self.n_vertices if vertices is None else len(self._rows(vertices)) // 3
            return np.zeros(batch + (n, 3))
        if vertices is not None and len(ws) > 1 and self._first_mode_worth(ws[0], vertices):
            # one identity over the batch, already contracted or wanted for many vertices:
            # its rows of the contracted core (the core's rows alone copy r_1 times more)
            core, left = self._first_mode_contracted([ws[0].reshape(-1, ws[0].shape[-1])[0]]
                                                     + list(ws[1:]))
            core = core[self._rows(vertices)]
            if math.prod(batch) > 1 and len(left) > 1:
                core, left = _contract_constant_modes(core, left)
            return _kron_product(core, left, batch)
        core = self._core_rows(vertices)
        if math.prod(batch) > 1:  # e.g. one identity for a whole clip: contract it once
            core, ws = self._batch_contracted(core, ws, vertices)
        elif vertices is None and len(ws) > 1:  # one frame: the identity of the frame before
            core, ws = self._first_mode_contracted(ws)
        return _kron_product(core, ws, batch)

    def clip_basis(self, weights: Weights) -> "ClipBasis":
        """A clip's Eq. (5) split in two: the core contracted once with every mode whose
        weights are the same in all frames (a track's identity), and the weights of the others.

        ``clip_basis(w).meshes(rows)`` equals ``synthesize({m: w[m][rows]})``: a clip's meshes
        made a few frames at a time, where and when they are needed, without holding them all.

        Parameters
        ----------
        weights : mapping mode name -> (F, r_k) array, or a sequence in mode order

        Returns
        -------
        ClipBasis
        """
        ws = self._weights_list(weights)
        n = self._batch_shape(ws)
        if len(n) != 1:
            raise ShapeError(f"a clip's weights must be (F, r_k), got batch shape {n}")
        ws = [np.broadcast_to(w, n + w.shape[-1:]) for w in ws]
        core, left = self._batch_contracted(self.core, ws, None) if n[0] > 1 else \
            self._first_mode_contracted(ws) if len(ws) > 1 else (self.core, ws)
        return ClipBasis(core, tuple(left), n[0])

    def _batch_contracted(self, core: np.ndarray, ws: list, vertices) -> tuple[np.ndarray, list]:
        """:func:`_contract_constant_modes` for a batch; when the first mode (the identity) is
        the only constant one and the whole mesh is wanted, its contraction is the memo of
        :meth:`_first_mode_contracted` (the same product: a clip's meshes and its single
        frames with that identity share it; 0.1 s a contraction for the default model)."""
        const = [bool((w == w.reshape(-1, w.shape[-1])[0]).all()) for w in ws]
        if vertices is None and len(ws) > 1 and const[0] and not any(const[1:]):
            return self._first_mode_contracted([ws[0].reshape(-1, ws[0].shape[-1])[0]]
                                               + list(ws[1:]))
        return _contract_constant_modes(core, ws)

    def _first_mode_contracted(self, ws: list) -> tuple[np.ndarray, list]:
        """The core contracted with ``ws[0]`` (one frame's first-mode weights), kept for the
        next call with the same weights (:data:`_FIRST_MODE`), and the other modes' weights."""
        w0 = np.ascontiguousarray(ws[0], dtype=np.float64).ravel()
        key = w0.tobytes()
        with _FIRST_MODE_LOCK:
            memo = _FIRST_MODE.setdefault(self, {})
            core = memo.get(key)
            if core is None:
                core = _contract_axis(self.core, 1, w0)
                while len(memo) >= _FIRST_MODE_KEPT:
                    memo.pop(next(iter(memo)))
                memo[key] = core
        return core, ws[1:]

    def _first_mode_worth(self, w0: np.ndarray, vertices: np.ndarray) -> bool:
        """Whether :meth:`synthesize` of ``vertices`` takes the rows of the core contracted
        with ``w0`` (:meth:`_first_mode_contracted`): ``w0`` the same in every row and that
        contraction kept already, or a selection of at least an eighth of the vertices (the
        contraction reads the core once, ~0.1 s for the default model; copying that many of
        its rows costs more, measured: 48 ms for the eye region's, against 4 ms)."""
        w = w0.reshape(-1, w0.shape[-1])
        if not (w == w[0]).all():
            return False
        if 8 * np.size(vertices) >= self.n_vertices:
            return True
        key = np.ascontiguousarray(w[0], dtype=np.float64).tobytes()
        with _FIRST_MODE_LOCK:
            return key in _FIRST_MODE.get(self, {})

    def _rows(self, vertices: np.ndarray) -> np.ndarray:
        """The core's rows ``(3m,)`` of ``vertices`` (x, y, z of each), checked: one list of
        integer indices (floats were truncated, a boolean mask read as indices 0 and 1, a 2-D
        selection flattened)."""
        a = np.asarray(vertices)
        if a.ndim != 1:
            raise ShapeError(f"vertices must be a 1-D array of vertex indices, got shape "
                             f"{a.shape}")
        if a.size and a.dtype.kind not in "iu":
            raise ShapeError(f"vertices must be integer vertex indices, got dtype {a.dtype}"
                             + (" (for a boolean mask give np.flatnonzero(mask))"
                                if a.dtype.kind == "b" else ""))
        v = a.astype(np.int64, copy=False)
        if v.size and (v.min() < 0 or v.max() >= self.n_vertices):
            raise ShapeError(f"vertex indices outside 0..{self.n_vertices - 1}")
        return (3 * v[:, None] + np.arange(3)).ravel()

    def _core_rows(self, vertices: np.ndarray | None) -> np.ndarray:
        return self.core if vertices is None else self.core[self._rows(vertices)]

    def mode_basis(self, mode: str | int, weights: Weights, *,
                   vertices: np.ndarray | None = None) -> np.ndarray:
        """Linear basis of one mode with the others fixed, Eq. (9).

        ``M_m = M ×_2 w_2ᵀ ... ×_{m-1} w_{m-1}ᵀ ×_{m+1} w_{m+1}ᵀ ... ×_N w_Nᵀ``, so that
        ``synthesize(w)[vertices] == mode_basis(m, w, vertices=vertices) @ w_m``.

        Parameters
        ----------
        mode : str or int
        weights : mapping or sequence of (r_k,) vectors
            The entry of ``mode`` itself is not used, but checked as the others are (real,
            finite, of the right length: :meth:`synthesize`'s check).
        vertices : (m,) int array, optional

        Returns
        -------
        (n_vertices or m, 3, r_m) float64
        """
        k = self.mode_index(mode)
        ws = self._weights_list(weights)
        first = 0
        if k != 0 and (vertices is None or self._first_mode_worth(ws[0], vertices)):
            out, _ = self._first_mode_contracted(ws)  # the identity's, kept (synthesize)
            if vertices is not None:
                out = out[self._rows(vertices)]
            first = 1
        else:
            out = self._core_rows(vertices)
        for j in reversed(range(first, self.n_modes)):
            if j != k:
                out = _contract_axis(out, j + 1 - first, ws[j])
        return out.reshape(-1, 3, self.ranks[k])

    # ----------------------------------------------------------------- identity & i/o
    @property
    def content_hash(self) -> str:
        """sha256 (hex) over every array and the metadata: identifies the model in track files.

        Computed once per model object (the arrays of a model are never changed in place).
        """
        h = _HASHES.get(self)
        if h is None:
            h = _HASHES[self] = _content_hash(self._arrays(), self._metadata())
        return h

    def _arrays(self) -> dict[str, np.ndarray]:
        arrays = {"core": self.core, "faces": self.faces}
        for k, U in enumerate(self.factors):
            arrays[f"factor_{k}"] = U
        for k, ev in enumerate(self.eigenvalues):
            arrays[f"eigenvalues_{k}"] = ev
        for name in ("uvs", "landmarks", "vertex_subset", "imputed"):
            val = getattr(self, name)
            if val is not None:
                arrays[name] = val
        return arrays

    def _metadata(self) -> dict:
        meta = {"magic": _MAGIC, "format_version": FORMAT_VERSION,
                "mode_names": list(self.mode_names), "labels": [list(l) for l in self.labels],
                "provenance": self.provenance}
        return meta

    def save(self, path: str | Path, *, overwrite: bool = True) -> Path:
        """Write the model to one ``.npz`` file atomically (versioned, with a content checksum)."""
        arrays = self._arrays()
        meta = self._metadata()
        meta["sha256"] = _content_hash(arrays, self._metadata())
        with atomic_path(path, overwrite=overwrite) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, metadata=np.array(json.dumps(meta, default=json_default)), **arrays)
        _remember_file(self, Path(path))
        return Path(path)


def json_default(o):
    """``json.dumps``' ``default``: numpy arrays as lists, numpy numbers as Python's, paths as
    text; TypeError for anything else."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _content_hash(arrays: Mapping[str, np.ndarray], meta: dict) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.reshape(-1).view(np.uint8))  # the bytes of tobytes(), without a copy
    h.update(json.dumps(meta, sort_keys=True, default=json_default).encode())
    return h.hexdigest()


def load_model(path: str | Path) -> MultilinearModel:
    """Read and validate a model file written by :meth:`MultilinearModel.save`.

    Raises
    ------
    ModelFileError
        Missing, truncated or altered file (checksum mismatch), not a model file, or a newer
        format version.

    Notes
    -----
    The sha256 and the scan for NaN and infinities are done once per file as it is on disk: a
    file whose inode, size and modification time are those it had when it last passed them is
    not read whole again (:mod:`facetransfer.io.verified`).
    """
    from .io.npz import read_npz

    p = Path(path)
    # the core is mapped, not read (hundreds of MB; its sha256 is verified below)
    data = read_npz(p, "model file", ModelFileError, mmap_min_bytes=MAP_MIN_BYTES)
    if "metadata" not in data:
        what = "it is a track file (as `facetransfer track` writes)" \
            if {"rotation", "mode_names"} <= set(data) else "it has no metadata"
        raise ModelFileError(f"{p} is not a facetransfer model file: {what}")
    try:
        meta = json.loads(str(data.pop("metadata")))
    except (json.JSONDecodeError, ValueError):
        raise ModelFileError(f"model file {p} has corrupt metadata") from None
    if not isinstance(meta, dict) or meta.get("magic") != _MAGIC:
        raise ModelFileError(f"{p} is not a facetransfer model file")
    try:
        version = int(meta.get("format_version", -1))
    except (TypeError, ValueError):
        raise ModelFileError(f"model file {p} has corrupt metadata (format_version)") from None
    if version > FORMAT_VERSION:
        raise ModelFileError(f"model file {p} has format version {version}, newer than this "
                             f"facetransfer reads ({FORMAT_VERSION}); upgrade facetransfer")
    expected = meta.pop("sha256", None)
    # a file that passed every check below, unchanged since: not hashed or scanned again
    known = isinstance(expected, str) and was_verified(p, expected)
    if not known and expected != _content_hash(data, meta):
        raise ModelFileError(f"model file {p} fails its checksum: it was altered or damaged")
    try:
        K = len(meta["mode_names"])
        _check_model_arrays(p, data, K, finite=not known)
        model = MultilinearModel(
            core=data["core"], factors=tuple(data[f"factor_{k}"] for k in range(K)),
            mode_names=tuple(meta["mode_names"]), labels=tuple(tuple(l) for l in meta["labels"]),
            faces=data["faces"], uvs=data.get("uvs"), landmarks=data.get("landmarks"),
            vertex_subset=data.get("vertex_subset"),
            eigenvalues=tuple(data[f"eigenvalues_{k}"] for k in range(K) if f"eigenvalues_{k}" in data),
            imputed=data.get("imputed"), provenance=meta.get("provenance", {}))
    except (KeyError, ValueError, TypeError, IndexError) as exc:  # ShapeError is a ValueError
        raise ModelFileError(f"model file {p} is incomplete or inconsistent: {exc}") from None
    if not known:
        remember_verified(p, expected)
    _HASHES[model] = expected  # verified above: the same sha256 that content_hash gives
    _remember_file(model, p)
    if any(_map_offset(a) is not None for a in data.values()):
        check_before_commit(functools.partial(check_not_written_over, weakref.ref(model)))
    return model


#: A model file's arrays of at least this many bytes are mapped from the file, not read
#: (:func:`load_model`): the default model's core is 0.45 GB.
MAP_MIN_BYTES = 1 << 24


def check_not_written_over(model) -> None:
    """Raise :class:`ModelFileError` if the file ``model`` (or a weak reference to it) was
    loaded from has been written over in place since (:func:`file_written_over`): its mapped
    core reads the new bytes, so what was computed with it may mix two models. A command's
    outputs check it before each is put in place (:func:`load_model` adds it to the command's
    :func:`facetransfer.io.atomic.commit_checks`): before, ``track``, ``transfer`` and
    ``puppet`` wrote such results as the old model's."""
    if isinstance(model, weakref.ref):
        model = model()
    if model is not None and file_written_over(model):
        raise ModelFileError(f"model file {_FILES[model][0]} was written over while this "
                             "command ran: the model, read from it as it is used, may have "
                             "mixed two models, so nothing more was written; run the command "
                             "again")


def _file_identity(path: Path) -> tuple | None:
    """``(device, inode, size, mtime ns)`` of the file at ``path``, None where there is none."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def _remember_file(model: MultilinearModel, path: Path) -> None:
    ident = _file_identity(path)
    if ident is not None:
        _FILES[model] = (path.absolute(), ident)


def model_file(model: MultilinearModel) -> Path | None:
    """The file (absolute) ``model`` was loaded from (:func:`load_model`) or last saved to
    (:meth:`MultilinearModel.save`), where that file is still the one it was then (the same
    device, inode, size and modification time); None otherwise (a model built in memory, a
    file replaced or removed since). Another process can load the same model from it: a batch
    run's workers do (:mod:`facetransfer.batch.model_ref`)."""
    path, ident = _FILES.get(model, (None, None))
    if path is None or _file_identity(path) != ident:
        return None
    return path


def file_written_over(model: MultilinearModel) -> bool:
    """Whether the file ``model`` was loaded from or saved to (:func:`model_file`) is at its
    path still the same file (device, inode) with other content: written over in place (a
    ``cp`` onto it), so that a core mapped from it (:func:`load_model`) reads its new bytes.
    False for a file replaced by another (a rename onto it, as :meth:`MultilinearModel.save`
    writes: the mapped one is kept as it was), removed, or unchanged, and for a model with no
    file.

    Another modification time is a change only where the content confirms it (read once,
    :func:`_same_content`): a file touched, or written over with an identical copy, was
    refused (fix54). Another size is a change without reading."""
    path, ident = _FILES.get(model, (None, None))
    if path is None:
        return False
    now = _file_identity(path)
    if now is None or now[:2] != ident[:2] or now == ident:
        return False
    with _SAME_LOCK:
        if _FILES.get(model, (None, None))[1] == now:
            return False                  # confirmed by another thread meanwhile
        if now[2] != ident[2] or not _same_content(model, path):
            return True
        _FILES[model] = (path, now)       # the same model: not read again
        return False


_SAME_LOCK = threading.Lock()   # one content check at a time (outputs check from threads)


def _same_content(model: MultilinearModel, path: Path) -> bool:
    """Whether the model file at ``path`` holds ``model``: its stated sha256 and its content's
    (not hashed again where recorded so as it is now, :mod:`facetransfer.io.verified`) are its
    ``content_hash``, its mapped arrays where the file holds them. False where unreadable."""
    from .io.npz import read_npz

    try:
        data = read_npz(path, "model file", ModelFileError, mmap_min_bytes=MAP_MIN_BYTES)
        meta = json.loads(str(data.pop("metadata")))
        stated = meta.pop("sha256", None)
        known = stated == model.content_hash and was_verified(path, stated)
        if stated != model.content_hash or not known and _content_hash(data, meta) != stated:
            return False
    except (ModelFileError, OSError, ValueError, KeyError, TypeError, AttributeError):
        return False
    remember_verified(path, stated)     # the loaded model's content: not hashed on next load
    return all(name in data and _map_offset(data[name]) == _map_offset(a)
               for name, a in model._arrays().items() if _map_offset(a) is not None)


def _map_offset(a: np.ndarray) -> int | None:
    """The offset in its file of the mapping ``a`` views (a file mapped into memory,
    :func:`facetransfer.io.npz.read_npz`), None where it views none."""
    while a is not None:
        if isinstance(a, np.memmap):
            return int(a.offset)
        a = a.base if isinstance(a.base, np.ndarray) else None
    return None


#: dtype kinds of the arrays of a model file (float: also integers; int: integers only)
_ARRAY_KINDS = {"core": "fiu", "faces": "iu", "uvs": "fiu", "landmarks": "iu",
                "vertex_subset": "iu", "imputed": "b"}


def _all_finite(a: np.ndarray) -> bool:
    """No NaN or infinity in ``a``: a NaN or an infinity makes the sum non-finite, so a finite
    sum settles it in one pass without a boolean copy (only a sum that overflows is checked
    element by element)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(a.sum()):
            return True
    return bool(np.isfinite(a).all())


def _check_model_arrays(p: Path, data: dict, n_modes: int, *, finite: bool = True) -> None:
    """Dtypes, finiteness (unless not ``finite``) and shapes the model class does not check;
    ModelFileError names ``p``."""
    for name, a in data.items():
        base = name.rsplit("_", 1)[0] if name[-1].isdigit() else name
        kinds = _ARRAY_KINDS.get(base, "fiu")
        if a.dtype.kind not in kinds:
            raise ModelFileError(f"model file {p}: {name} has dtype {a.dtype}, expected "
                                 + {"fiu": "numbers", "iu": "integers", "b": "booleans"}[kinds])
        if finite and a.dtype.kind == "f" and not _all_finite(a):
            raise ModelFileError(f"model file {p}: {name} has NaN or infinite values")
    core = data["core"]
    n = core.shape[0] // 3 if core.ndim else 0
    for name, shape in (("uvs", (n, 2)), ("landmarks", None), ("vertex_subset", (n,))):
        a = data.get(name)
        if a is None:
            continue
        if (shape is not None and a.shape != shape) or a.ndim != 1 and name != "uvs":
            raise ModelFileError(f"model file {p}: {name} has shape {a.shape}, expected "
                                 f"{shape or '(68,)'}")
    for k in range(n_modes):
        ev = data.get(f"eigenvalues_{k}")
        if ev is not None and ev.ndim != 1:
            raise ModelFileError(f"model file {p}: eigenvalues_{k} must be 1-D, got {ev.shape}")


def build_model(dataset: FaceDataset, ranks: Mapping[str, int] | None = None, *,
                refine: bool = True, variance: float | None = None, max_iter: int = 50,
                imputed: np.ndarray | None = None) -> MultilinearModel:
    """Build the multilinear model of a complete data set, Eq. (4).

    Parameters
    ----------
    dataset : FaceDataset
        Must be complete (fill missing cells with :mod:`facetransfer.impute` first).
    ranks : mapping mode name -> rank, optional
        Modes not named keep all components (or as many as ``variance`` needs).
    refine : bool
        Refine the N-mode SVD by alternating least squares (HOOI, §3).
    variance : float, optional
        Retained-variance truncation for modes without an explicit rank.
    imputed : (d_1, ..., d_K) bool, optional
        Cells that were imputed, recorded in the model.

    Returns
    -------
    MultilinearModel

    References
    ----------
    Vlasic et al. 2005, §3 (N-mode SVD, ALS) and §4.3, Eq. (4).
    """
    if not dataset.mask.all():
        missing = dataset.missing_cells()
        shown = "; ".join("/".join(c) for c in missing[:10])
        more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
        raise DatasetError(f"{len(missing)} missing cells ({shown}{more}): impute them first "
                           f"(--impute ppca)")
    ranks = dict(ranks or {})
    unknown = set(ranks) - set(dataset.mode_names)
    if unknown:
        raise ValueError(f"ranks given for unknown mode(s) {sorted(unknown)}; modes are "
                         f"{', '.join(dataset.mode_names)}")
    T = dataset.data_tensor()  # (3n, d_1..d_K), Fig. 3
    rank_list: list[int | None] = [None] + [ranks.get(n) for n in dataset.mode_names]
    for name, r, d in zip(dataset.mode_names, rank_list[1:], dataset.shape):
        if r is not None and not 1 <= r <= d:
            raise ValueError(f"rank {r} for mode {name!r} must be between 1 and {d}")
    if refine:
        dec = tl.hooi(T, rank_list, skip=(0,), variance=variance, max_iter=max_iter)
    else:
        dec = tl.nmode_svd(T, rank_list, skip=(0,), variance=variance)
    prov = dict(dataset.provenance)
    prov.update({"ranks": {n: int(r) for n, r in zip(dataset.mode_names, dec.ranks[1:])},
                 "refine": bool(refine), "relative_errors": [float(e) for e in dec.errors],
                 "facetransfer_version": _version()})
    return MultilinearModel(
        core=np.ascontiguousarray(dec.core), factors=tuple(dec.factors[1:]),
        mode_names=tuple(dataset.mode_names), labels=tuple(tuple(l) for l in dataset.labels),
        faces=np.asarray(dataset.faces, dtype=np.int64),
        uvs=None if dataset.uvs is None else np.asarray(dataset.uvs, dtype=np.float64),
        landmarks=None if dataset.landmarks is None else np.asarray(dataset.landmarks, np.int64),
        vertex_subset=None if dataset.vertex_subset is None else np.asarray(dataset.vertex_subset,
                                                                             np.int64),
        eigenvalues=tuple(dec.eigenvalues[1:]),
        imputed=None if imputed is None else np.asarray(imputed, dtype=bool), provenance=prov)


def _version() -> str:
    from . import __version__

    return __version__


def _kron(ws, batch: tuple) -> np.ndarray:
    """The outer product of the mode weights ``ws`` (each ``batch + (r_k,)``, broadcast),
    flattened in C order to match the core's layout: ``batch + (r_1 ... r_K,)``."""
    kron = np.ones(batch + (1,))
    for w in ws:
        w = np.broadcast_to(w, batch + w.shape[-1:])
        kron = (kron[..., :, None] * w[..., None, :]).reshape(batch + (-1,))
    return kron


def _kron_product(core: np.ndarray, ws: list, batch: tuple) -> np.ndarray:
    """Eq. (5) as one matrix product: the outer product of the mode weights (a Kronecker vector
    of length r_1 ... r_K, C order to match the core's layout) times the unfolded core
    ``(3n, r_1, ..., r_K)``; returns ``batch + (n, 3)``."""
    kron = _kron(ws, batch)
    # the unfolded core on the left (C-contiguous: BLAS reads it once, in order); with the
    # core transposed on the right, numpy's product is 2-10x slower (measured)
    flat = core.reshape(core.shape[0], -1)
    out = (flat @ kron.reshape(-1, kron.shape[-1]).T).T
    return out.reshape(batch + (-1, 3))


@dataclass(frozen=True, eq=False)
class ClipBasis:
    """:meth:`MultilinearModel.clip_basis`: a clip's core, contracted with its constant modes.

    Attributes
    ----------
    core : (3n, r_j, ...) float64
        The core over the modes left (one, the expression, for a track).
    weights : tuple of (F, r_j) arrays
        Their weights in every frame.
    n_frames : int
    """

    core: np.ndarray
    weights: tuple
    n_frames: int

    @property
    def modes_left(self) -> int:
        """How many modes vary over the clip (a frame's mesh costs the product of their ranks
        multiply-adds per coordinate)."""
        return len(self.weights)

    def meshes(self, rows: np.ndarray) -> np.ndarray:
        """The meshes ``(len(rows), n_vertices, 3)`` float64 of frames ``rows`` (Eq. 5),
        C-contiguous.

        For a few frames the product runs the other way round from :func:`_kron_product`
        (weights on the left, the core transposed): its rows are then the meshes, and for 8-32
        frames it costs a third of the CPU (0.16 against 0.45 ms a frame at 16, measured)."""
        rows = np.asarray(rows, np.intp)
        kron = _kron([w[rows] for w in self.weights], (len(rows),))
        flat = self.core.reshape(self.core.shape[0], -1)
        return (kron @ flat.T).reshape(len(rows), -1, 3)


def _contract_constant_modes(core: np.ndarray, ws: list[np.ndarray]
                             ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Contract the core with every mode whose weights are the same over the batch (Eq. 5).

    ``M ×_k w_kᵀ`` is taken once for such a mode instead of inside every row's Kronecker
    vector: a clip's meshes with one identity cost ``F·r_expr`` instead of ``F·r_id·r_expr``
    multiply-adds per coordinate.

    Parameters
    ----------
    core : (3n, r_1, ..., r_K)
    ws : K arrays (..., r_k)

    Returns
    -------
    core : (3n, r_j, ...) over the modes left
    ws : their weights
    """
    left = []
    out = core
    for j in reversed(range(len(ws))):
        w = ws[j].reshape(-1, ws[j].shape[-1])
        if not (w == w[0]).all():
            left.append(ws[j])
            continue
        out = _contract_axis(out, 1 + j, w[0])  # the modes before j are all still there
    return out, left[::-1]


def _contract_axis(T: np.ndarray, axis: int, w: np.ndarray) -> np.ndarray:
    """``T`` contracted with the vector ``w`` over ``axis`` (a mode product ``×_k wᵀ``).

    The last axis is a matrix-vector product; an inner axis an ``einsum`` over it, which
    reads the core in place (``tensordot`` would copy it transposed; a batched ``matmul`` of
    ``w`` with every row's small matrix was 10x slower, measured on the default model)."""
    if axis == T.ndim - 1:
        return T @ w
    keep = [d for d in range(T.ndim) if d != axis]
    if axis == 0 or T.nbytes < _SPLIT_BYTES or (os.cpu_count() or 1) < 2:
        return np.einsum(T, list(range(T.ndim)), w, [axis], keep)
    return _contract_halves(T, axis, w, keep)


#: A core at least this large is contracted in two halves of its rows at once
#: (:func:`_contract_halves`): the default model's 470 MB in 25 ms instead of 45 (measured).
_SPLIT_BYTES = 32 << 20


def _contract_halves(T: np.ndarray, axis: int, w: np.ndarray, keep: list) -> np.ndarray:
    """:func:`_contract_axis` over an inner ``axis``, the first half of ``T``'s rows on a
    thread of its own (einsum runs without the interpreter lock) and the second here: the
    contraction reads the whole array, which one core cannot do at the memory's pace. Each
    output element is the same sum in the same order as one einsum's (bit for bit). A thread
    per call, not a pool: a forked child inherits no pool's dead workers."""
    out = np.empty(tuple(T.shape[d] for d in keep), np.result_type(T, w))
    h = T.shape[0] // 2
    spec = (list(range(T.ndim)), [axis], keep)
    failed: list = []

    def first_half() -> None:
        try:
            np.einsum(T[:h], spec[0], w, spec[1], spec[2], out=out[:h])
        except BaseException as exc:  # noqa: BLE001 - raised again below, by the caller
            failed.append(exc)

    first = threading.Thread(target=first_half, name="contract-half", daemon=True)
    first.start()
    try:
        np.einsum(T[h:], spec[0], w, spec[1], spec[2], out=out[h:])
    finally:
        first.join()
    if failed:
        raise failed[0]
    return out
