"""The rewritten face's size in pixels, and the rewrite's pixel settings grown with it.

The rewrite's settings in pixels were chosen on the data folder's clips, faces whose eyes'
centres lie 102-137 px apart (:func:`face_span` over every frame of ``driving_d6``,
``driving_d9``, ``WDA_KatieHill_000`` and ``face_2``, their own tracks and their new ones with
another clip's expressions): the blend's feather and erosion
(:class:`facetransfer.rewrite_options.BlendOptions`), the mouth's, the eye region's and the
jaw region's feathers, the eye region's lid fade and shading scale, the jaw region's hue scale
and its margin around a tongue (:data:`facetransfer.jaw.LOOK_GROW`), the pastes' compare ring
and rejection (:mod:`facetransfer.patch`), the rim's depth tolerance
(:mod:`facetransfer.rim`) and the soft edge of the target's own pixels
(:mod:`facetransfer.rewrite`). On a face two or three times larger (HD footage, a phone's
portrait video) the same pixels are a seam two or three times narrower for the face: the jaw
region's edge showed as a step across the cheek at the mouth's height, where the same clip at
512 px showed a soft one (BENCHMARKS.md, "Fifty-fourth session (helper large54)"). So each is
multiplied by :func:`face_scale`: 1 up to :data:`FACE_SPAN` (those clips render as before, to
the bit), proportional to the face beyond, without a step at it (the settings in whole pixels
are rounded, and step where their rounding does: the blend's 2-px erosion at a factor of 1.25).
A clip's frames take their shot's factor (:func:`shot_scale`), a frame rewritten alone its own.
The data folder's ``breakingbad.jpg`` (1920x1080, eyes 158-161 px apart) is a larger face: as a
target its settings are 1.09-1.11 times these.

The settings that are about the pixel grid itself stay in pixels: the half-pixel rule of
:mod:`facetransfer.unmoved` (a resampling's error) and the grids' steps. The eyeballs' rim
(:data:`facetransfer.eyeballs.RIM_WIDTH`) is a share of the eye's width, as the eyeballs'
other sizes are.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FACE_SPAN", "face_span", "face_scale", "shot_scale"]

#: Pixels between the centres of the eyes up to which the rewrite's pixel settings are used as
#: they are: the data folder's clips, where they were chosen (102-137 px), and a margin.
FACE_SPAN = 145.0


def face_span(vertices: np.ndarray, camera, eye_loops) -> float:
    """Pixels between the centres of the mesh's two eye holes at the camera's scale.

    Parameters
    ----------
    vertices : (n, 3) float
        The face in model coordinates (the closed mesh, or the model's vertices).
    camera : WeakPerspective or another camera with ``project``
        A weak-perspective camera (Eq. (7)) gives its scale times the centres' distance: the
        face's size, not foreshortened by a turn of the head. Another camera gives the distance
        of the centres' projections.
    eye_loops : tuple of (k,) int
        The eye holes' boundary loops (:attr:`facetransfer.topology.MeshTopology.eye_loops`).

    Returns
    -------
    float
        NaN without two eye loops.
    """
    if len(eye_loops) != 2:
        return float("nan")
    V = np.asarray(vertices, np.float64)
    c = np.stack([V[np.asarray(loop, np.int64)].mean(axis=0) for loop in eye_loops])  # (2, 3)
    from .render import WeakPerspective

    if isinstance(camera, WeakPerspective):
        return float(camera.scale * np.linalg.norm(c[0] - c[1]))
    p = np.asarray(camera.project(c), np.float64)
    return float(np.hypot(*(p[0] - p[1])))


def face_scale(span: float) -> float:
    """The factor of the rewrite's pixel settings for a face whose eyes' centres lie ``span``
    pixels apart (:func:`face_span`): 1 up to :data:`FACE_SPAN`, ``span / FACE_SPAN`` beyond;
    1 where ``span`` is not finite."""
    span = float(span)
    return max(1.0, span / FACE_SPAN) if np.isfinite(span) else 1.0


def shot_scale(vertices: np.ndarray, track, eye_loops, frames) -> float:
    """:func:`face_scale` of a shot: of the median of :func:`face_span` over its ``frames``
    (indices into ``track``, each frame's camera with the one face ``vertices``: the eyes'
    distance does not change with the expression); 1 without a frame.

    One factor for the shot's frames, not each its own: the settings in whole pixels step
    where their rounding does, and a face whose measure moved about such a step from frame to
    frame had its outline flicker (the blend's erosion, 2 px at 1.249 and 3 at 1.251: on a
    1280x1280 clip's frame 19, 1,097 pixels of the outline changed by more than 8 levels, up
    to 111: BENCHMARKS.md, "Fifty-fifth session (helper large55)")."""
    spans = [face_span(vertices, track.camera(int(i)), eye_loops) for i in frames]
    return face_scale(np.nanmedian(spans)) if spans and not np.isnan(spans).all() else 1.0
