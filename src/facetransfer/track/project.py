"""Operations on a whole track that need no footage: taking frames, re-projecting landmarks.

Pure functions on :class:`facetransfer.track.result.Track`, shared by the transfer
(:mod:`facetransfer.transfer`), the track's consumers (:mod:`facetransfer.track.obtain`, batch
joins, dials) and the tests.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..arkit import attach_activations
from ..errors import TrackError

__all__ = ["held_lost", "nearest_tracked", "take_frames", "project_landmarks"]


def take_frames(track, idx: np.ndarray):
    """Frames ``idx`` (int array) of a track, as a new track (its shots kept where ``idx`` is a
    run of consecutive frames)."""
    idx = np.asarray(idx, dtype=np.int64)
    run = idx.size > 0 and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size))
    starts = tuple(int(a - idx[0]) for a in track.shot_starts
                   if run and idx[0] < a < idx[0] + idx.size)
    return dataclasses.replace(
        track, shot_starts=starts, rotation=track.rotation[idx], scale=track.scale[idx],
        translation=track.translation[idx],
        weights={n: w[idx] for n, w in track.weights.items()},
        landmarks2d=track.landmarks2d[idx], confidence=track.confidence[idx],
        lost=track.lost[idx], info={"file": track.info["file"]} if track.info.get("file") else {},
        blendshapes=None if track.blendshapes is None else track.blendshapes[idx],
        detections2d=None if track.detections2d is None else track.detections2d[idx],
        occluded=None if track.occluded is None else track.occluded[idx])


def nearest_tracked(lost) -> np.ndarray:
    """Per frame, the frame whose values it shows: itself where the face is tracked, else the
    nearest frame not ``lost`` (the earlier on ties); itself everywhere when every one is lost.

    Parameters
    ----------
    lost : (F,) bool

    Returns
    -------
    (F,) int64
    """
    lost = np.asarray(lost, bool)
    idx = np.arange(lost.size)
    good = np.flatnonzero(~lost)
    if good.size == 0:
        return idx
    k = np.clip(np.searchsorted(good, idx), 1, max(good.size - 1, 1))
    before, after = good[k - 1], good[np.minimum(k, good.size - 1)]
    near = np.where(np.abs(after - idx) < np.abs(idx - before), after, before)
    return np.where(lost, near, idx)


def held_lost(track):
    """``track`` with each lost frame holding its nearest tracked frame's pose, weights,
    landmarks and activations (:func:`nearest_tracked`), as the capture tracker stores them
    (``capture._fill_lost``); ``lost`` and ``confidence`` kept. The paper's KLT tracker keeps
    the flow's drifting state there, a landmarks track and ``batch --chunk``'s joins other
    frames': ``puppet`` and ``export`` show lost frames through this one rule. The track
    itself where no lost frame would change."""
    idx = nearest_tracked(track.lost)
    if np.array_equal(idx, np.arange(track.n_frames)):
        return track
    return dataclasses.replace(
        track, rotation=track.rotation[idx], scale=track.scale[idx],
        translation=track.translation[idx],
        weights={n: w[idx] for n, w in track.weights.items()},
        landmarks2d=track.landmarks2d[idx],
        blendshapes=None if track.blendshapes is None else track.blendshapes[idx])


def project_landmarks(track, model):
    """The track with ``landmarks2d`` recomputed from its weights and pose (Eq. (5), (7)).

    Parameters
    ----------
    track : Track
    model : MultilinearModel
        Must have ``landmarks`` (68,).

    Returns
    -------
    Track
    """
    if model.landmarks is None:
        raise TrackError("the model has no landmark vertices")
    lm = model.synthesize({n: track.weights[n] for n in model.mode_names},
                          vertices=model.landmarks)  # (F, 68, 3)
    Y = np.einsum("fij,fvj->fvi", track.rotation[:, :2], lm)  # (F, 68, 2)
    px = np.empty_like(Y)
    px[..., 0] = (track.scale[:, None] / track.pixel_aspect) * Y[..., 0] \
        + track.translation[:, None, 0]                       # Eq. (7), the pixels' aspect
    px[..., 1] = -track.scale[:, None] * Y[..., 1] + track.translation[:, None, 1]
    return attach_activations(dataclasses.replace(track, landmarks2d=px, info={}), model)
