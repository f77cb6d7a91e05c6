"""Cuts: where an edited clip changes shot, from its detections.

The capture fits one identity to a whole clip (§5.1 accumulates it over all frames), and holds
each frame's activations and pose near the previous frame's. A clip edited from several shots
(an interview cut between two people, a close-up cut into a wide shot) breaks both: one identity
was fitted to two people. :func:`shot_starts` finds the frames where a new shot starts: the
picture changes at once (:attr:`facetransfer.track.detect.ClipDetections.change`, the 32x32
thumbnails' difference from the previous frame, many times the changes around it) and, where
a face is found on both sides, the point flow fails for most points. The capture then fits each
shot on its own (:func:`facetransfer.track.capture.capture_detections`).

Measured on the data folder's 4 clips (no cuts; 1,920 frames) and three edited ones (a cut
between two people, between two clips of one person, and into a closer framing of the same
clip): at the cuts the change is 25-144 times the median around it (36-72 levels) and the flow
fails for 96-100 % of the points; elsewhere at most 4.7 times (12.2 levels at most). The flow
alone would not do: it fails for every point at the first frame of a clip's second detection
process, which has no flow into it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CUT_RATIO", "CUT_LEVELS", "CUT_FLOW_FAILED", "MIN_SHOT", "SAME_FACE_SHARE",
           "shot_starts", "shot_spans", "shot_detections", "joined_shots", "shots_from",
           "shot_inputs", "same_face"]

#: A cut's picture change over the median change of the frames around it (±15).
CUT_RATIO = 12.0
#: ... and at least this many grey levels (a flicker of a still picture is not a cut).
CUT_LEVELS = 15.0
#: Where both frames show a face, the share of points whose flow failed at a cut.
CUT_FLOW_FAILED = 0.8
#: The shortest shot, frames: two cuts closer than this (a flash, a frame dropped from
#: another shot) are neither kept.
MIN_SHOT = 8
#: Two captures' identity weights closer than this share (root mean square) of the median
#: distance between the model's training identities are one person's. Measured with the
#: default model (training identities 0.203 apart) on the data folder's 4 people, 100-frame
#: parts captured alone: one person's parts 0.011-0.022 apart, two people's 0.054-0.099; the
#: share puts the line at 0.035.
SAME_FACE_SHARE = 0.17


def shot_starts(det) -> list[int]:
    """The frames where a new shot starts (never 0), in order (module notes); none for
    detections without :attr:`~facetransfer.track.detect.ClipDetections.change`."""
    change = det.change
    if change is None or det.n_frames < 2 * MIN_SHOT:
        return []
    c = np.asarray(change, np.float64)
    n = len(c)
    cand = []
    for t in range(1, n):
        if not np.isfinite(c[t]) or c[t] < CUT_LEVELS:
            continue
        near = np.r_[c[max(1, t - 15):t], c[t + 1:t + 16]]
        near = near[np.isfinite(near)]
        if near.size and c[t] < CUT_RATIO * max(float(np.median(near)), 0.5):
            continue
        if _faces_both(det, t) and np.isnan(det.flow[t, :, 0]).mean() < CUT_FLOW_FAILED:
            continue
        cand.append(t)
    return [t for k, t in enumerate(cand) if t >= MIN_SHOT and n - t >= MIN_SHOT
            and (k == 0 or t - cand[k - 1] >= MIN_SHOT)
            and (k == len(cand) - 1 or cand[k + 1] - t >= MIN_SHOT)]


def same_face(model, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether identity weights ``a`` and ``b`` (r,) of ``model`` are one person's
    (:data:`SAME_FACE_SHARE`): for a part of a clip captured apart from the part where its
    identity was solved (a chunk of ``batch track --chunk``), which may begin after a cut to
    another person."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return bool(np.sqrt(np.mean(d * d)) < SAME_FACE_SHARE * _identity_spread(model))


def _identity_spread(model) -> float:
    """The median root-mean-square distance between the model's training identities'
    weights."""
    k = model.mode_index("identity")
    W = np.stack([model.training_weights(k, label) for label in model.labels[k]])
    i, j = np.triu_indices(len(W), 1)
    return float(np.median(np.sqrt(np.mean((W[i] - W[j]) ** 2, axis=1))))


def _faces_both(det, t: int) -> bool:
    return bool(np.isfinite(det.points[t - 1]).all() and np.isfinite(det.points[t]).all())


def shot_spans(starts: list[int], n_frames: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of each shot of a clip of ``n_frames`` cut at ``starts``."""
    edges = [0, *starts, int(n_frames)]
    return list(zip(edges[:-1], edges[1:]))


def shot_detections(det, start: int, stop: int):
    """Frames ``start .. stop - 1`` of detections, as a clip of their own (no flow into, no
    picture change at, its first frame)."""
    from dataclasses import replace

    flow = det.flow[start:stop].copy()
    flow[0] = np.nan
    change = None
    if det.change is not None:
        change = det.change[start:stop].copy()
        change[0] = np.nan
    return replace(det, points=det.points[start:stop], flow=flow,
                   points478=None if det.points478 is None else det.points478[start:stop],
                   scores=None if det.scores is None else det.scores[start:stop],
                   change=change, shown=None if det.shown is None else det.shown[start:stop])


def joined_shots(tracks: list, spans: list[tuple[int, int]]):
    """One track of a clip from its shots' tracks (each ``spans[k][1] - spans[k][0]`` frames;
    None for a shot without a face: :func:`_held`, marked lost)."""
    from dataclasses import replace

    done = [k for k, t in enumerate(tracks) if t is not None]
    parts = [_held(tracks, spans, done, k) if t is None else t for k, t in enumerate(tracks)]
    return replace(_concat(parts), info=dict(tracks[done[0]].info),
                   shot_starts=tuple(a for a, _ in spans[1:]))


def _held(tracks: list, spans: list, done: list, k: int):
    """Shot ``k`` without a face, marked lost: each frame holds the nearest tracked frame of
    the shots beside it (the last of the one before, the first of the one after, the earlier
    on a tie), not the nearer shot's for every frame, which would make a head held 10 frames at
    its pose before a black gap snap at its end."""
    from dataclasses import replace

    from .project import take_frames

    a, b = spans[k]
    before = [d for d in done if d < k]
    after = [d for d in done if d > k]
    i = np.arange(a, b)
    if before and after:
        use_after = (spans[after[0]][0] - i) < (i - (spans[before[-1]][1] - 1))
    else:
        use_after = np.full(b - a, not before)
    parts = []
    for flag, n in _runs(use_after):
        j = after[0] if flag else before[-1]
        parts.append(take_frames(tracks[j], np.full(n, 0 if flag else tracks[j].n_frames - 1)))
    return replace(_concat(parts), lost=np.ones(b - a, bool), confidence=np.zeros(b - a))


def _runs(flags: np.ndarray) -> list[tuple[bool, int]]:
    """``(value, length)`` of each run of equal values of ``flags`` (F,) bool."""
    edges = np.flatnonzero(np.diff(flags.astype(np.int8))) + 1
    return [(bool(flags[s]), int(e - s)) for s, e in
            zip(np.r_[0, edges], np.r_[edges, flags.size])]


def _concat(parts: list):
    """Tracks of consecutive frames as one (:func:`joined_shots`' arrays)."""
    from dataclasses import replace

    def cat(name):
        arrays = [getattr(t, name) for t in parts]
        return None if any(x is None for x in arrays) else np.concatenate(arrays)

    if len(parts) == 1:
        return parts[0]
    return replace(parts[0], rotation=cat("rotation"), scale=cat("scale"),
                   translation=cat("translation"), landmarks2d=cat("landmarks2d"),
                   confidence=cat("confidence"), lost=cat("lost"),
                   blendshapes=cat("blendshapes"), detections2d=cat("detections2d"),
                   weights={m: np.concatenate([t.weights[m] for t in parts])
                            for m in parts[0].weights})


def shots_from(first: int, n: int, target_frames, target_track, new_track, source_track,
               source_index):
    """``(start, stop, inputs)`` of each shot of a rewrite of ``n`` frames from frame
    ``first`` on (the shots of ``target_track.shot_starts``; :func:`shot_inputs`)."""
    for a, b in shot_spans([c for c in target_track.shot_starts if c < n], n):
        if b > first:
            yield a, b, shot_inputs(a, b, n, target_frames, target_track, new_track,
                                    source_track, source_index)


def shot_inputs(start: int, stop: int, n: int, target_frames, target_track, new_track,
                source_track, source_index):
    """``(target frames, target track, new track, source track, source index)`` of frames
    ``start .. stop - 1`` of a rewrite of ``n`` frames (all of them for the whole clip): a shot
    rewritten as a clip of its own (:func:`facetransfer.rewrite_clip.rewrite_frames`), so that its
    reference frames (the eyes', the jaw's, the lips' colour) are its own."""
    if (start, stop) == (0, n):
        return target_frames, target_track, new_track, source_track, source_index
    from .project import take_frames

    idx = np.arange(start, stop)
    return (target_frames[start:stop], take_frames(target_track, idx),
            take_frames(new_track, idx),
            None if source_track is None else take_frames(source_track, idx),
            np.asarray(source_index)[idx] if source_index is not None else
            (None if source_track is None else idx))
