"""Long clips in overlapping chunks: the split, the blend at the seams, and the seam's size.

A clip of ``F`` frames longer than ``chunk`` is cut into ``K`` chunks of at most ``chunk`` frames,
each overlapping the next by ``overlap`` frames. The identity is one for the whole clip: the
first chunk is tracked as a clip of its own (its identity is solved, §5.1), the others with that
identity held fixed (the tracker's ``fixed={"identity": w}``), in parallel. The tracks are
joined by a linear cross-fade over each overlap: the later chunk's weight rises from ``1/(O+1)``
to ``O/(O+1)`` over the ``O`` shared frames. Rotations are interpolated on the sphere (slerp,
``R_a exp(a log(R_a^T R_b))``), scales in log space, translations and per-frame weights linearly;
a frame lost in one chunk takes the other's state. The landmarks are cross-faded as the pose is
(a capture's landmarks carry its clip's offset from the model); the ARKit activations are then
recomputed from the blended expression weights (Eq. (A) of :mod:`facetransfer.arkit`).

Beyond the paper: Vlasic et al. track a clip in one sequence of passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .manifest import BatchError

__all__ = ["Chunk", "plan_chunks", "crossfade", "slerp_rotations", "join_tracks",
           "join_detections", "SeamReport", "seam_difference"]


@dataclass(frozen=True)
class Chunk:
    """Frames ``start`` (inclusive) to ``stop`` (exclusive) of a clip, the ``index``-th chunk."""

    index: int
    start: int
    stop: int

    @property
    def n_frames(self) -> int:
        return self.stop - self.start


#: The shortest ``--chunk`` ``batch track`` takes: a chunk is captured as a clip of its own
#: (2-frame chunks were taken, each fitted alone: 13.8 px off the whole clip's track).
MIN_CHUNK = 10


def plan_chunks(n_frames: int, chunk: int, overlap: int) -> tuple[Chunk, ...]:
    """Split ``n_frames`` into the fewest overlapping chunks of at most ``chunk`` frames.

    Parameters
    ----------
    n_frames : int
    chunk : int
        Largest chunk; ``0`` (or ``n_frames <= chunk``) gives one chunk, the whole clip.
    overlap : int
        Frames shared by neighbouring chunks, ``1 <= overlap <= chunk // 2``; less for a clip
        too short to hold it (``F < (K + 1) overlap`` for ``K`` chunks), so that no frame is in
        more than two chunks.

    Returns
    -------
    tuple of Chunk
        Consecutive chunks covering ``0..n_frames``; the steps between their starts differ by at
        most one frame.

    Raises
    ------
    BatchError
        ``n_frames < 1``, ``chunk < 0``, or an overlap out of range.
    """
    n, c, o = int(n_frames), int(chunk), int(overlap)
    if n < 1:
        raise BatchError(f"a clip needs at least one frame, got {n}")
    if c < 0:
        raise BatchError(f"--chunk must be >= 0 (0 = never split), got {c}")
    if c == 0 or n <= c:
        return (Chunk(0, 0, n),)
    if not 1 <= o <= c // 2:
        raise BatchError(f"--overlap must be between 1 and --chunk/2 = {c // 2}, got {o}")
    k = -(-(n - o) // (c - o))  # ceil: fewest chunks whose steps fit chunk - overlap
    o = min(o, n // (k + 1))  # steps >= overlap: no frame in three chunks (short clips)
    steps = [(n - o) // k + (1 if i < (n - o) % k else 0) for i in range(k)]
    starts = np.concatenate([[0], np.cumsum(steps)[:-1]])
    return tuple(Chunk(i, int(s), int(s + st + o)) for i, (s, st) in enumerate(zip(starts, steps)))


def crossfade(n: int) -> np.ndarray:
    """Weights ``(n,)`` of the later chunk over an ``n``-frame overlap: ``(j + 1) / (n + 1)``."""
    return (np.arange(n) + 1.0) / (n + 1.0)


def slerp_rotations(Ra: np.ndarray, Rb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Spherical interpolation ``R_a exp(alpha log(R_a^T R_b))`` per frame.

    Parameters
    ----------
    Ra, Rb : (n, 3, 3) float64
        Rotation matrices.
    alpha : (n,) float64
        0 gives ``Ra``, 1 gives ``Rb``.

    Returns
    -------
    (n, 3, 3) float64
    """
    from scipy.spatial.transform import Rotation

    a, b = Rotation.from_matrix(Ra), Rotation.from_matrix(Rb)
    rel = (a.inv() * b).as_rotvec()  # (n, 3), the shortest arc
    return (a * Rotation.from_rotvec(rel * np.asarray(alpha, float)[:, None])).as_matrix()


def _blend(A: dict, B: dict, alpha: np.ndarray, constant: tuple[str, ...]) -> dict:
    """Blend the per-frame fields of two tracks over an overlap (``alpha``: weight of B)."""
    la, lb = A["lost"], B["lost"]
    a = alpha.copy()
    a[la & ~lb] = 1.0  # lost in A only: take B
    a[lb & ~la] = 0.0
    lin = lambda x, y: (1 - a).reshape((-1,) + (1,) * (x.ndim - 1)) * x + \
        a.reshape((-1,) + (1,) * (x.ndim - 1)) * y  # noqa: E731
    out = {"rotation": slerp_rotations(A["rotation"], B["rotation"], a),
           "scale": np.exp(lin(np.log(A["scale"]), np.log(B["scale"]))),
           "translation": lin(A["translation"], B["translation"]),
           "landmarks2d": lin(A["landmarks2d"], B["landmarks2d"]),
           "confidence": lin(A["confidence"], B["confidence"]),
           "lost": la & lb,
           "weights": {m: (A["weights"][m] if m in constant else
                           lin(A["weights"][m], B["weights"][m])) for m in A["weights"]}}
    return out


def _fields(track, sl=slice(None)) -> dict:
    return {"rotation": track.rotation[sl], "scale": track.scale[sl],
            "translation": track.translation[sl], "landmarks2d": track.landmarks2d[sl],
            "confidence": track.confidence[sl], "lost": track.lost[sl],
            "weights": {m: w[sl] for m, w in track.weights.items()}}


def _put(full: dict, part: dict, sl: slice) -> None:
    for k in ("rotation", "scale", "translation", "landmarks2d", "confidence", "lost"):
        full[k][sl] = part[k]
    for m, w in part["weights"].items():
        full["weights"][m][sl] = w


def join_tracks(tracks, chunks, model, *, constant: tuple[str, ...] = ("identity",)):
    """Join the tracks of overlapping chunks into one track of the whole clip.

    Parameters
    ----------
    tracks : sequence of Track
        One per chunk, in order; ``tracks[k].n_frames == chunks[k].n_frames``; the same model,
        frame size and frame rate.
    chunks : sequence of Chunk
        From :func:`plan_chunks`.
    model : MultilinearModel
        The model of the tracks (the ARKit activations are recomputed with it).
    constant : tuple of str
        Modes constant over the clip (taken from the first chunk, not blended); over each
        shot of a clip edited from several (the chunks' ``shot_starts``: taken from the chunk
        where the shot starts).

    Returns
    -------
    Track
        ``sum(chunk lengths) - overlaps`` frames; fps, size, source and model hash of the first
        track; the chunks' landmarks cross-faded as the pose is (not re-projected from the
        joined weights: a capture's landmarks carry its clip's offset from the model,
        :mod:`facetransfer.track.capture`), ARKit activations recomputed from the joined
        expression weights (:func:`facetransfer.arkit.attach_activations`); the detections joined
        (:func:`join_detections`), so that a transfer from the joined track still carries the
        source's lips (:mod:`facetransfer.lips`).

    Raises
    ------
    BatchError
        Mismatched counts, lengths, frame sizes or models.
    """
    from ..arkit import attach_activations
    from ..track.result import Track
    from ..track.shots import shot_spans

    tracks, chunks = list(tracks), list(chunks)
    _check_chunk_tracks(tracks, chunks)
    t0 = tracks[0]
    F = chunks[-1].stop
    full = _fields(t0)
    full = {k: (np.zeros((F,) + v.shape[1:], v.dtype) if k != "weights" else
                {m: np.zeros((F, w.shape[1])) for m, w in v.items()}) for k, v in full.items()}
    _put(full, _fields(t0), slice(0, chunks[0].stop))
    for prev, c, t in zip(chunks[:-1], chunks[1:], tracks[1:]):
        o = prev.stop - c.start  # frames shared with the previous chunk
        if o < 0 or c.start < prev.start:
            raise BatchError(f"chunk {c.index} does not follow chunk {prev.index}")
        shared = slice(c.start, prev.stop)
        _put(full, _blend(_fields_of(full, shared), _fields(t, slice(0, o)), crossfade(o),
                          constant), shared)
        _put(full, _fields(t, slice(o, None)), slice(prev.stop, c.stop))
    starts = _shot_starts(tracks, chunks)
    for m in constant:  # one identity for the clip, or a shot of an edited one
        if m in full["weights"]:
            for a, b in shot_spans(starts, F):
                k, c = next((k, c) for k, c in enumerate(chunks) if c.start <= a < c.stop)
                full["weights"][m][a:b] = tracks[k].weights[m][a - c.start]
    joined = Track(fps=t0.fps, frame_size=t0.frame_size, rotation=full["rotation"],
                   scale=full["scale"], translation=full["translation"],
                   weights=full["weights"], landmarks2d=full["landmarks2d"],
                   confidence=np.clip(full["confidence"], 0, 1), lost=full["lost"],
                   model_hash=t0.model_hash, mode_names=t0.mode_names, source=t0.source,
                   detections2d=join_detections(tracks, chunks), pixel_aspect=t0.pixel_aspect,
                   shot_starts=starts, source_facts=t0.source_facts)
    return attach_activations(joined, model)


def _shot_starts(tracks, chunks) -> tuple[int, ...]:
    """The clip's cuts (:attr:`facetransfer.track.Track.shot_starts`) from its chunks' (a cut
    in an overlap seen by both chunks once; cuts closer than a shortest shot, once)."""
    from ..track.shots import MIN_SHOT

    seen = sorted({c.start + s for t, c in zip(tracks, chunks) for s in t.shot_starts})
    starts: list[int] = []
    for s in seen:
        if not starts or s - starts[-1] >= MIN_SHOT:
            starts.append(s)
    return tuple(starts)


def join_detections(tracks, chunks) -> np.ndarray | None:
    """The chunks' detections (``Track.detections2d``, (n, 68, 2) each) as one (F, 68, 2) array,
    None unless every chunk has them. Detections are measurements of a frame, not estimates to
    blend: a frame two chunks share takes the nearer chunk's (the first half of the overlap the
    earlier chunk's, the rest the later one's), or the other's where that chunk found no face."""
    if not tracks or any(t.detections2d is None for t in tracks):
        return None
    D = np.full((chunks[-1].stop, 68, 2), np.nan)
    prev = None
    for c, t in zip(chunks, tracks):
        d = np.asarray(t.detections2d, np.float64)
        o = 0 if prev is None else prev.stop - c.start      # frames shared with the previous
        keep = D[c.start:c.start + o]                         # the previous chunk's, a view
        mine = d[:o]
        first = np.arange(o) < o - o // 2                     # the earlier chunk's half
        take = np.where(first[:, None, None], np.isnan(keep) & ~np.isnan(mine), ~np.isnan(mine))
        keep[take] = mine[take]
        D[c.start + o:c.stop] = d[o:]
        prev = c
    return D


def _check_chunk_tracks(tracks: list, chunks: list) -> None:
    """BatchError unless there is one track per chunk, of its length, all of one frame size and
    model."""
    if len(tracks) != len(chunks) or not tracks:
        raise BatchError(f"{len(tracks)} chunk tracks for {len(chunks)} chunks")
    t0 = tracks[0]
    for t, c in zip(tracks, chunks):
        if t.n_frames != c.n_frames:
            raise BatchError(f"chunk {c.index} (frames {c.start}-{c.stop - 1}) was tracked to "
                             f"{t.n_frames} frames, expected {c.n_frames}")
        if t.frame_size != t0.frame_size or t.model_hash != t0.model_hash \
                or t.mode_names != t0.mode_names:
            raise BatchError(f"chunk {c.index} has another frame size or model than chunk 0")


def _fields_of(full: dict, sl: slice) -> dict:
    return {k: (v[sl].copy() if k != "weights" else {m: w[sl].copy() for m, w in v.items()})
            for k, v in full.items()}


@dataclass(frozen=True)
class SeamReport:
    """How much a chunked track differs from the whole-clip track, at the seams and elsewhere.

    Attributes
    ----------
    seams : tuple of int
        The frame at the middle of each overlap.
    seam_px : tuple of float
        Mean landmark distance (pixels) between the two tracks over the frames within
        ``radius`` of each seam.
    elsewhere_px : float
        The same mean over the frames farther than ``radius`` from every seam.
    motion_px : tuple of float
        Largest frame-to-frame landmark motion (mean over the 68 landmarks, pixels) of the
        chunked track within ``radius`` of each seam: a step at a seam shows here, above
        ``whole_motion_px``.
    whole_motion_px : tuple of float
        The same for the whole-clip track over the same frames (the footage's own motion).
    iod_px : float
        Mean inter-ocular distance (outer eye corners) of the whole track, for scale.
    """

    seams: tuple[int, ...]
    seam_px: tuple[float, ...]
    elsewhere_px: float
    motion_px: tuple[float, ...]
    whole_motion_px: tuple[float, ...]
    iod_px: float


def seam_difference(whole, joined, chunks, *, radius: int = 10) -> SeamReport:
    """Compare a chunked track with the whole-clip track around its seams.

    Parameters
    ----------
    whole, joined : Track
        The same clip tracked in one piece and in ``chunks``.
    chunks : sequence of Chunk
    radius : int
        Frames either side of a seam counted as "at the seam".

    Returns
    -------
    SeamReport
    """
    if whole.n_frames != joined.n_frames:
        raise BatchError(f"tracks of {whole.n_frames} and {joined.n_frames} frames")
    d = np.linalg.norm(whole.landmarks2d - joined.landmarks2d, axis=2).mean(axis=1)  # (F,)
    motion = lambda t: np.r_[np.linalg.norm(np.diff(t.landmarks2d, axis=0), axis=2).mean(
        axis=1), 0.0]  # noqa: E731  (F,): frame i to i + 1
    mj, mw = motion(joined), motion(whole)
    seams = [int((c.start + p.stop) // 2) for p, c in zip(chunks[:-1], chunks[1:])]
    near = np.zeros(whole.n_frames, bool)
    seam_px, mot, wmot = [], [], []
    for s in seams:
        lo, hi = max(0, s - radius), min(whole.n_frames, s + radius + 1)
        near[lo:hi] = True
        seam_px.append(float(d[lo:hi].mean()))
        mot.append(float(mj[lo:hi - 1].max()) if hi - 1 > lo else 0.0)
        wmot.append(float(mw[lo:hi - 1].max()) if hi - 1 > lo else 0.0)
    iod = float(np.linalg.norm(whole.landmarks2d[:, 36] - whole.landmarks2d[:, 45], axis=1).mean())
    rest = d[~near]
    return SeamReport(tuple(seams), tuple(seam_px), float(rest.mean()) if rest.size else 0.0,
                      tuple(mot), tuple(wmot), iod)
