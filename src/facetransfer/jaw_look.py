"""The jaw region's appearance rule: what the target's mouth shows that the model does not.

The jaw region (:mod:`facetransfer.jaw`) takes the closed-mouth reference frame's texture where
the target's own tracked expression moved the skin (:func:`facetransfer.jaw.jaw_strengths`).
A tongue stuck out over the lower lip, the teeth, the mouth's dark gap or a lip pressed out
are not in the model (the FaceKit has no tongue shape, MediaPipe no tongueOut score): the
tracked geometry barely moves there, and the region kept the frame's own texture, the tongue
included (issue 13: a red-orange glow on the chin under the new lower lip of the judge's
``open`` pair, ``WDA_KatieHill_000`` -> ``driving_d6``, frames ~75-95:
``benchmarks/bench_jaw_appearance.py``). So a vertex of the region near the mouth also takes
the reference frame where the current frame's colour departs from the reference frame's in a
way lighting does not explain (:func:`look_strengths`):

- the colours are read under each vertex of the target's tracked mesh in each frame
  (:func:`facetransfer.region_weights.usual_weights_of`'s reading, ``log(c + 8)``);
- the measure is the **hue** step, the distance of the log-chromaticities (each colour's log
  minus its mean over the channels) of the current and the reference frame at the vertex,
  less the region's median step (the region's colour match): a change of light or exposure
  scales the channels together, which the log-chromaticity does not see, and tints the
  region smoothly, which the median takes out. CIELAB's a* and b* shrink with the brightness:
  the same skin 30 % darker steps by 7 in a*, b* (a quarter of a tongue's 28 on it), by 0.007
  in log-chromaticity (a fortieth of the tongue's 0.29). A darkness term was left out: near
  the mouth the steps of the brightness (less the region's median) that the geometric rule
  leaves to the frame reach 0.28 (log) in the 99.9th percentile of ``driving_d6``'s frames
  without any tongue (shadows), and the dark gaps of ``WDA_KatieHill_000``'s talking mouth
  step in hue too;
- in pixels dark in both frames the step is scaled down (:func:`dark_scale`,
  :data:`LOOK_DARK`): a level of noise moves the log-chromaticity by ~1/(c + 8), past the
  ramp in a clip at a sixth of the usual brightness;
- only near the mouth (:func:`mouth_reach`, :data:`LOOK_REACH`): at the region's outer edge
  (the jaw line, under the ears) the current frame's steps are hair, an ear-ring or the
  background beyond the outline, which the current frame must keep.

:func:`facetransfer.jaw.jaw_texture` takes the larger of the two rules' strengths at each
vertex; :func:`facetransfer.jaw.paint_jaw` does not take the region's hue from the pixels of
this rule (the hue match spreading the tongue's red over the pasted chin was most of the
glow: with the hue match off, the glow was gone), nor lets the paste's rejection give them
back to the current frame (a lip pressed out dark red, unlike the reference's skin by more than
:data:`facetransfer.patch.REJECT`, came back as a stripe under the new lip's corner).
"""

from __future__ import annotations

import numpy as np

from .region_weights import _vertex_colours, smoothstep

__all__ = ["LOOK_RAMP", "LOOK_REACH", "LOOK_DARK", "MEDIAN_STRIDE", "mouth_reach",
           "hue_steps", "dark_scale", "look_strengths"]

#: :func:`look_strengths`' ramp on the hue step (the log-chromaticity distance, less the
#: region's median): a vertex starts to take the reference frame at the first value and takes
#: it fully from the second. On the open pair's target (``driving_d6``, 120 frames) the steps
#: of the vertices near the mouth that the geometric rule leaves to the frame have a 99th
#: percentile of 0.05 and a 99.9th of 0.11; the tongue over the lower lip steps by only ~0.2
#: (its pink is near the lips' red), and a ramp of 0.15-0.3 left the glow; 0.05-0.12 removes
#: it (``benchmarks/bench_jaw_appearance.py``). For scale: the same skin 30 % darker steps by
#: 0.007 (CIELAB's a*, b*: by 7, a quarter of a tongue's 28), a tongue on it by 0.29.
LOOK_RAMP = (0.05, 0.12)
#: Model units (cm, the default model's): the rule applies fully to the vertices within the
#: first distance of the mouth's inner contour (the mean person's face), not beyond the
#: second. A tongue stuck out over the lower lip reaches ~3 cm below it; the jaw line and the
#: skin under the ears lie 5-13 cm from the mouth (of the default model's 2,238 vertices of
#: the region, 730 take the rule fully, 1,339 not at all).
LOOK_REACH = (3.0, 4.5)
#: :func:`look_strengths`' darkness (pixel levels): where both frames' colour at a vertex is
#: darker than this (the geometric mean of its channels), its hue step is scaled by
#: ``(c + 8) / (LOOK_DARK + 8)``. A level of noise moves the log-chromaticity by ~1/(c + 8):
#: on ``driving_d6`` at 15 % of its brightness (the skin near the mouth at 16) 87 of its 899
#: vertices near the mouth took the reference frame in a frame without a tongue (18 at its own
#: brightness, 18 at 35 %), 24 with the scale; the tongue's frames 64 (65 at its own).
LOOK_DARK = 24.0
#: :func:`look_strengths` reads the region's median step (its colour match) from every this
#: many of its vertices (and the rule's own, near the mouth, all): on issue 13's 300-frame
#: target the rule took 0.15 s of the region textures' 0.53, made while the forked source is
#: tracked, on the path to the render's first frame.
MEDIAN_STRIDE = 4


def mouth_reach(model, topo, verts: np.ndarray, reach: tuple[float, float] = LOOK_REACH
                ) -> np.ndarray:
    """``(m,) float32`` in [0, 1]: 1 at the vertices ``verts`` (m,) of the model within
    ``reach[0]`` of the nearest vertex of the mouth's triangles (``topo.mouth_faces``, the
    model's vertices of them) on the model's mean person, 0 beyond ``reach[1]``, a smoothstep
    between."""
    faces = np.asarray(topo.faces)[np.asarray(topo.mouth_faces, np.int64)]
    mv = np.unique(faces)
    mv = mv[mv < model.n_vertices]
    verts = np.asarray(verts, np.int64)
    if mv.size == 0 or verts.size == 0:
        return np.zeros(verts.size, np.float32)
    from scipy.spatial import cKDTree

    V = np.asarray(model.synthesize(model.default_weights(),
                                    vertices=np.concatenate([verts, mv])), np.float64)
    d = cKDTree(V[verts.size:]).query(V[:verts.size])[0]
    return (1.0 - smoothstep(d, reach)).astype(np.float32)


def hue_steps(logc: np.ndarray, ref: np.ndarray, sample: np.ndarray | None = None
              ) -> np.ndarray:
    """``(k, m) float32``: per frame and vertex the hue step of ``logc`` (k, m, 3), the
    colours' logs, from ``ref`` (m, 3), the reference frame's: the Euclidean length of the
    difference of the log-chromaticities (the logs less their mean over the channels), less
    that difference's median over the vertices (per frame and channel), or over the columns
    ``sample`` of them (an even sample of the region: the median of a quarter of its vertices
    is the region's to a few thousandths, for a quarter of the sort)."""
    c = logc - logc.mean(axis=-1, keepdims=True)
    r = ref - ref.mean(axis=-1, keepdims=True)
    d = c - r[None]
    d -= np.median(d if sample is None else d[:, sample], axis=1, keepdims=True)
    return np.sqrt((d * d).sum(-1)).astype(np.float32)


def dark_scale(logc: np.ndarray, ref: np.ndarray, dark: float = LOOK_DARK) -> np.ndarray:
    """``(k, m) float32`` in (0, 1]: per frame and vertex, ``(c + 8) / (dark + 8)`` of the
    brighter of ``logc`` (k, m, 3) and ``ref`` (m, 3), the colours' ``log(c + 8)`` (``c + 8``
    the geometric mean of the channels'), 1 from ``dark`` up: what a hue step is worth over
    the pixels' noise (:data:`LOOK_DARK`)."""
    top = np.maximum(logc.mean(axis=-1), ref.mean(axis=-1)[None])
    return np.minimum(np.exp(top) / (float(dark) + 8.0), 1.0).astype(np.float32)


def look_strengths(frames, track, model, verts: np.ndarray, reference: int,
                   reach: np.ndarray, n_frames: int | None = None, *,
                   ramp: tuple[float, float] = LOOK_RAMP, chunk: int = 256) -> np.ndarray:
    """How much of the reference frame each vertex takes for its appearance: ``(F, m)
    float32`` in [0, 1], ``F`` the track's frames.

    The smoothstep over ``ramp`` of :func:`hue_steps` of the colours under each vertex
    ``verts`` (m,) of the target's tracked mesh in each frame (of the first ``n_frames``, not
    lost; 0 in the others) against the ``reference`` frame's, in dark pixels scaled by
    :func:`dark_scale`, times ``reach`` (m,) (:func:`mouth_reach`).

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8
        The target video.
    track : Track
        The target's.
    model : MultilinearModel
    verts : (m,) int64
        The region's vertices of the model.
    reference : int
        The frame the region is textured from.
    reach : (m,) float32
        Per vertex, how much the rule applies (:func:`mouth_reach`).
    n_frames : int, optional
    ramp : (float, float)
        :data:`LOOK_RAMP`.
    chunk : int
        Frames read at a time.
    """
    verts = np.asarray(verts, np.int64)
    n = len(track.lost)
    out = np.zeros((n, verts.size), np.float32)
    m = min(len(frames), n) if n_frames is None else min(int(n_frames), len(frames), n)
    reach = np.asarray(reach, np.float32)
    rows = np.flatnonzero(~np.asarray(track.lost, bool)[:m])
    if not reach.any() or rows.size == 0:
        return out
    # read: the vertices near the mouth (the rule's) and every MEDIAN_STRIDE-th of the region
    # (its median step is the colour match; the sample keeps the region's own proportions)
    sample = np.zeros(verts.size, bool)
    sample[::MEDIAN_STRIDE] = True
    read = np.flatnonzero((reach > 0) | sample)
    near = reach[read] > 0
    cols = np.flatnonzero(sample[read])
    ref = _vertex_colours(frames, track, model, verts[read], np.array([int(reference)]))[0]
    for lo in range(0, rows.size, chunk):
        k = rows[lo:lo + chunk]
        logc = _vertex_colours(frames, track, model, verts[read], k)
        steps = hue_steps(logc, ref, cols) * dark_scale(logc, ref)
        out[np.ix_(k, read[near])] = smoothstep(steps[:, near], ramp) * reach[read[near]]
    return out
