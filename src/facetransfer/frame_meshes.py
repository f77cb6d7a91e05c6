"""A clip's meshes frame by frame (Eq. 5), synthesised a few frames at a time for the renderer
(:func:`facetransfer.rewrite_clip.rewrite_frames`), on whichever of its threads asks.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["MESH_CHUNK", "FrameMeshes", "constant_if_nearly"]

#: Frames of a clip's meshes synthesised together (:class:`FrameMeshes`).
MESH_CHUNK = 16
#: Chunks of each kind kept for the threads (:class:`FrameMeshes`): the one being rendered
#: and the one before it, which a thread a frame or two behind may still ask for.
CHUNKS_KEPT = 2


class FrameMeshes:
    """A clip's meshes (Eq. 5) frame by frame, synthesised a few frames at a time.

    Each kind (``"new"``, ``"target"``, ``"source"``: a track) gets its
    :meth:`~facetransfer.model.MultilinearModel.clip_basis` once, on the first thread that
    asks (the core contracted with the track's identity, 0.1 s for the default model); then
    :data:`MESH_CHUNK` consecutive frames are one product, made by the first thread that asks
    for one of them (another asking meanwhile waits for it) and shared by the threads: the
    kind's last :data:`CHUNKS_KEPT` chunks are kept (two threads render alternate frames, so
    each product was made twice when each thread kept its own). A frame's mesh is a view of
    its chunk's array (a new array per chunk: a view stays valid). Nothing
    the size of the clip is held: the clip's meshes up front cost
    the render's set-up 0.6 s on one core and 200 MB of fresh memory (BENCHMARKS.md,
    "Fourteenth session"). A track whose identity changes over the clip (more than one mode
    left) is synthesised whole, once, as one chunk the threads share.
    """

    def __init__(self, model, tracks: dict, n: int) -> None:
        self.model, self.tracks, self.n = model, tracks, n
        self._bases: dict = {}
        self._lock = threading.Lock()
        self._chunks: dict = {}     # kind -> ((first frame, meshes), ...), newest first
        self._making = {kind: threading.Lock() for kind in tracks}

    def __contains__(self, kind: str) -> bool:
        return kind in self.tracks

    def basis(self, kind: str):
        """The kind's :class:`~facetransfer.model.ClipBasis` over the first ``n`` frames."""
        with self._lock:
            basis = self._bases.get(kind)
            if basis is None:
                tr = self.tracks[kind]
                names = self.model.mode_names if kind == "new" else tr.mode_names
                basis = self._bases[kind] = self.model.clip_basis(
                    {m: constant_if_nearly(tr.weights[m][:self.n]) for m in names})
        return basis

    def frame(self, kind: str, i: int) -> np.ndarray:
        """The mesh ``(n_vertices, 3)`` float64 of frame ``i`` of ``kind`` (C-contiguous)."""
        mesh = self._held(kind, i)
        if mesh is not None:
            return mesh
        with self._making[kind]:    # one thread makes a chunk; one asking meanwhile waits
            mesh = self._held(kind, i)
            if mesh is not None:
                return mesh
            basis = self.basis(kind)
            k = MESH_CHUNK if basis.modes_left <= 1 else self.n
            i0 = i - i % k
            chunk = (i0, basis.meshes(np.arange(i0, min(i0 + k, self.n))))
            with self._lock:
                self._chunks[kind] = (chunk,) + self._chunks.get(kind, ())[:CHUNKS_KEPT - 1]
        return chunk[1][i - i0]

    def _held(self, kind: str, i: int) -> np.ndarray | None:
        """Frame ``i``'s mesh of ``kind`` from a chunk kept, or None."""
        with self._lock:
            for i0, meshes in self._chunks.get(kind, ()):
                if i0 <= i < i0 + len(meshes):
                    return meshes[i - i0]
        return None


def constant_if_nearly(w: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """A mode's weights ``(F, r)``, their first row repeated when every row is within ``rtol``
    of it (relative to its largest entry): an identity a few ulps apart over the clip (from a
    track resampled or filtered elsewhere) is contracted once (:meth:`facetransfer.model.
    MultilinearModel.clip_basis`), not carried through every frame's product (~300 times the
    cost, and the clip's meshes made whole)."""
    w = np.asarray(w)
    if w.ndim != 2 or len(w) < 2:
        return w
    tol = rtol * max(1.0, float(np.abs(w[0]).max()))
    return np.broadcast_to(w[0], w.shape) if float(np.abs(w - w[0]).max()) <= tol else w
