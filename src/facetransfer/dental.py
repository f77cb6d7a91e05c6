"""The dental arches behind a face's lips and the teeth's shading along them.

Shared by the two places that put teeth in a mouth: a rewrite whose new mouth opens wider than
the target's frames show (:mod:`facetransfer.mouth_inside` draws the teeth on these arches, seen
along the camera's view) and the exported face (:mod:`facetransfer.export.teeth` stands a strip
of teeth on each). Pure numpy on one mesh: no frame, no camera (importing the rewrite's module
costs an export 2 s of its imports).

Beyond the paper (its §6 takes the mouth from the source video).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .topology import MeshTopology

__all__ = ["ARCH_CURVE", "ARCH_BEHIND", "LOWER_SHOW", "LOWER_SHADE", "TEETH_PARTS", "PART_WIDTH",
           "PART_SHADE", "DentalArch", "dental_arch", "teeth_shade"]

#: The dental arch the teeth are drawn on, seen through the opening along the camera's view in
#: the head's frame: a parabola ``z = front - ARCH_CURVE x²`` (eye widths) about the mouth's
#: middle, its front :data:`ARCH_BEHIND` eye widths behind the upper (the lower) lip's inner
#: edge at the middle. The canines, 17 mm from the middle, lie 9 mm behind the incisors (an
#: adult's upper arch; an eye width 26.9 mm): 0.33 / 0.64² = 0.81. A head turned away shows
#: the near side's teeth and hides the far side's behind the far lip's corner; a frontal head
#: sees each point of the arch straight behind the opening's point, as the flat band did.
ARCH_CURVE = 0.81
ARCH_BEHIND = 0.05
#: How far the lower teeth show over the lower lip, in eye widths (about 2.7 mm).
LOWER_SHOW = 0.1
#: The lower teeth, in the lower lip's shadow, at this fraction of the upper teeth's light.
LOWER_SHADE = 0.7
#: Where the teeth part, eye widths from the middle: the central incisors (8.5 mm), the
#: lateral ones (6.5 mm), the canines (7.5 mm) and the first premolars (7 mm), these two seen on
#: a turned head's near side (:func:`facetransfer.mouth_inside._seen_as`); the line's
#: half-width (eye widths) and how much it darkens.
TEETH_PARTS = (0.0, 0.32, 0.56, 0.84, 1.1)
PART_WIDTH = 0.012
PART_SHADE = 0.15


@dataclass(frozen=True)
class DentalArch:
    """The dental arches behind a face's lips (:func:`dental_arch`), in the head's frame.

    Each is ``z = front - ARCH_CURVE (x - middle)² / eye`` (:data:`ARCH_CURVE`, in eye widths).

    Attributes
    ----------
    middle, half : float
        The mouth's middle x and half-width (the inner-lip loop's).
    eye : float
        The eye width (corner to corner, the two eyes' mean): the teeth's scale.
    upper, lower : float
        The upper and the lower arch's front z: :data:`ARCH_BEHIND` eye widths behind the
        upper (the lower) lip's inner edge at its foremost over the middle third.
    upper_edge, lower_edge : float
        The y of the upper lip's inner edge at its lowest, of the lower lip's at its highest,
        over the middle third (the loop's centre height where it has no point there).
    """

    middle: float
    half: float
    eye: float
    upper: float
    lower: float
    upper_edge: float
    lower_edge: float

    def z(self, x: np.ndarray, front: float) -> np.ndarray:
        """``(n,)``: the z of the arch whose front is ``front`` at the x's ``x`` (n,)."""
        return front - ARCH_CURVE * (np.asarray(x, np.float64) - self.middle) ** 2 / self.eye


def dental_arch(V: np.ndarray, topo: MeshTopology, eyes: np.ndarray) -> DentalArch:
    """The dental arches of the face ``V`` (n, 3) (one frame's mesh, the head's frame), from its
    inner-lip loop (``topo.mouth_loop``) and its eye corners ``eyes`` (4,) (iBUG 36, 39, 42,
    45): the arches a rewrite draws the teeth on
    (:func:`facetransfer.mouth_inside._inside_colours`) and the exported teeth stand on
    (:mod:`facetransfer.export.teeth`)."""
    loop = V[topo.mouth_loop, 0]
    E = V[eyes]
    eye = 0.5 * (np.linalg.norm(E[0] - E[1]) + np.linalg.norm(E[2] - E[3]))
    half = 0.5 * (loop.max() - loop.min())
    middle = 0.5 * (loop.min() + loop.max())
    upper, lower = _middle_lips(V, topo, middle, half)
    at = float(V[topo.mouth_loop, 1].mean())
    z = float(V[topo.mouth_loop, 2].max())
    return DentalArch(float(middle), float(half), float(eye),
                      float((float(upper[:, 2].max()) if len(upper) else z) - ARCH_BEHIND * eye),
                      float((float(lower[:, 2].max()) if len(lower) else z) - ARCH_BEHIND * eye),
                      float(upper[:, 1].min()) if len(upper) else at,
                      float(lower[:, 1].max()) if len(lower) else at)


def _middle_lips(V: np.ndarray, topo: MeshTopology, middle: float, half: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(upper, lower)`` (m, 3): the points of the closed mesh ``V``'s inner-lip loop over the
    middle third of the mouth (``middle`` its x, ``half`` its half-width) above and below the
    loop's mean height: the upper and the lower lips' inner edges there."""
    loop = V[topo.mouth_loop]
    mid = np.abs(loop[:, 0] - middle) < max(half / 3.0, 1e-12)
    centre = float(loop[:, 1].mean())
    return loop[mid & (loop[:, 1] >= centre)], loop[mid & (loop[:, 1] < centre)]


def teeth_shade(colour: np.ndarray, x: np.ndarray, span: float, eye: float) -> np.ndarray:
    """``(n, 3)``: the teeth's ``colour`` (3,) at the arch's points ``x`` (n,) from the mouth's
    middle: darker toward the mouth's corners (``span`` the teeth's half-width), parted at
    the incisors (:data:`TEETH_PARTS`, eye widths ``eye``)."""
    side = np.clip(1.0 - np.abs(x) / span, 0.0, 1.0)
    light = 0.45 + 0.55 * (1.0 - (1.0 - side) ** 2)                      # the corners' dark
    parts = eye * np.asarray(TEETH_PARTS)       # eye widths (before: taken as model units)
    parted = 1.0 - PART_SHADE * np.exp(-((np.abs(x)[:, None] - parts) ** 2).min(axis=1)
                                       / (PART_WIDTH * eye) ** 2)
    return colour[None, :] * (light * parted)[:, None]
