"""The colours of what the model's skin does not cover: the eyeballs and the mouth's inside.

One palette for the three places that draw them: the puppet (:mod:`facetransfer.puppet_face`,
``facetransfer puppet`` and ``render``), the ``view`` page (:mod:`facetransfer.export.viewer`
hands it this dict) and a rewrite whose new mouth opens wider than the target's frames ever
show (:mod:`facetransfer.mouth_inside`, which scales it to the target's own light). Written
once so that they cannot drift apart (the fifty-second session's previews had two palettes,
the page's iris a ``sienna``, its mouth a near black).

Beyond the paper (it textures the mouth from the source video, §6, and renders no eyes).
"""

from __future__ import annotations

from types import MappingProxyType

__all__ = ["PALETTE", "CAVITY_BACK", "TEETH_SHOW", "TEETH_SPAN"]

#: The colours (RGB, 0-255). Each is what a surface facing a frontal light shows: ``skin`` and
#: the eyeball are shaded by their lights, the mouth's inside is not lit. ``iris`` to
#: :data:`facetransfer.puppet_face.IRIS_RIM` of the way from the pupil's edge, then toward
#: ``limbus`` (the iris's dark rim) at its edge; ``cavity`` the mouth's inside at the lips,
#: :data:`CAVITY_BACK` of it at the back; ``teeth`` the teeth.
PALETTE = MappingProxyType({
    "skin": (205, 170, 150),
    "sclera": (232, 228, 218),
    "iris": (124, 80, 48),
    "limbus": (52, 32, 20),
    "pupil": (12, 10, 10),
    "cavity": (96, 34, 32),
    "teeth": (222, 216, 198),
})
#: The mouth's inside at its back (the mouth fan's centre; the page's cone's apex and the
#: head's inside): ``PALETTE["cavity"]`` times this.
CAVITY_BACK = 0.5
#: How far the upper teeth show below the upper lip of an open mouth, in eye widths (corner to
#: corner): 0.3 of FaceKit's 2.69 cm, about the 8 mm of an upper incisor not under the lip.
TEETH_SHOW = 0.3
#: The upper teeth span this fraction of the mouth's half-width about its middle (each side of
#: it: the middle 55 % of the mouth).
TEETH_SPAN = 0.55
