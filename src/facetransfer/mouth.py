"""The source's mouth in a rewritten face (§6, Fig. 7D): the skin around it, its inside, and the
colours it takes.

The rewrite (:mod:`facetransfer.rewrite`) textures the mouth's triangles from the mouth's source
(the source frame, or the texture function of §6) and pastes them into the new face. Two
people's skin and two videos' light differ there, so the pasted mouth is first scaled to the
face's colours by a smooth gain (:func:`facetransfer.patch.match_outline`) fitted on a few rings
of skin triangles around it (:func:`mouth_ring_faces`), seen in both the source's frame and the
face: per channel on the lips and the skin they bring along, one gain for the three channels on
the mouth's inside (:func:`inside_mouth`, the teeth and tongue), whose hue is the source's own.
Where no skin around the mouth is seen (the texture function's mouth) an offset pinned at the
mouth's outline (a membrane, :func:`facetransfer.composite.membrane_blend`) does it instead.

References
----------
Vlasic et al. 2005, §6 (the mouth from the source video); Pérez et al. 2003 (the membrane).
"""

from __future__ import annotations

import numpy as np

from .composite import mask_box, membrane_blend, membrane_crop, over
from .eyes import faces_around
from .patch import match_outline_into, ring_inset
from .topology import MeshTopology

__all__ = ["MOUTH_RING", "MOUTH_GAIN_RANGE", "mouth_ring_faces", "inside_mouth", "blend_mouth",
           "mouth_gain_range"]

#: Rings of triangles around the mouth over which its gain is fitted (:func:`mouth_ring_faces`).
MOUTH_RING = 3
#: Per-channel gains allowed between the source's skin and the target's around the mouth: two
#: people under two lights differ more than one person's frames
#: (:data:`facetransfer.patch.GAIN_RANGE`, 0.7-1.4).
MOUTH_GAIN_RANGE = (0.4, 2.5)


def inside_mouth(tri_id: np.ndarray, topo: MeshTopology) -> np.ndarray | None:
    """(H, W) bool: the pixels of the mouth-closing fan (:attr:`MeshTopology.mouth_fan`: the
    mouth's inside, teeth, tongue and the dark cavity, which the lips' warp puts there,
    :mod:`facetransfer.lips`); None without a fan."""
    fan = topo.mouth_fan
    if fan.stop == fan.start:
        return None
    return (tri_id >= fan.start) & (tri_id < fan.stop)


def blend_mouth(T: np.ndarray, face_img: np.ndarray, face_mask: np.ndarray,
                mouth_img: np.ndarray, mask: np.ndarray, ring: np.ndarray | None,
                feather: float, inside: np.ndarray | None = None, *,
                scale: float = 1.0) -> np.ndarray:
    """``face_img`` with the source's mouth pasted where ``mask`` (H, W) bool, scaled per
    channel by the smooth gain of the face's colours over the source's on ``ring`` (H, W) bool,
    the skin around the mouth (:func:`facetransfer.patch.match_outline`, no rejection: the
    mouth is the source's wherever it differs), its outline feathered over ``feather`` pixels;
    written into ``face_img`` in place, on the box of the mouth and its ring. The mouth's
    inside (``inside`` (H, W) bool, :func:`inside_mouth`) takes one gain for the three channels
    instead: the ratio of two people's skin carries their skin tones as well as the two videos'
    light, and per channel it tinted the teeth (green-white on ``make demo``'s pair, whose
    target's skin is yellower than the source's), where the lips and the skin they bring along
    take the target's hue. Without a ring (the §6 texture function's mouth, which has no skin
    around it) or with fewer than 8 of its pixels in sight: :func:`_membrane_mouth`.
    ``scale``: the factor of the gain fit's pixel settings for the face's size
    (:func:`facetransfer.patch.ring_inset`; ``feather`` is given scaled)."""
    sl = mask_box(mask if ring is None else mask | ring, ring_inset(scale))
    if sl is None:
        return face_img
    m, fm = mask[sl], face_mask[sl]
    compare = None if ring is None else ring[sl] & fm
    if compare is None or np.count_nonzero(compare) < 8:
        return _membrane_mouth(T, face_img, face_mask, mouth_img, mask, feather)
    match_outline_into(face_img[sl], mouth_img[sl], m, fm, face_img[sl], feather=feather,
                       compare=compare, reject=None, reject_where=None,
                       origin=(sl[1].start, sl[0].start),
                       gain_range=mouth_gain_range(face_img[sl], mouth_img[sl], compare),
                       grey_where=None if inside is None else inside[sl], scale=scale)
    return face_img


def mouth_gain_range(face: np.ndarray, part: np.ndarray, compare: np.ndarray
                     ) -> tuple[float, float]:
    """The clip of the mouth's gains: :data:`MOUTH_GAIN_RANGE` widened by the two frames'
    exposure where it lies outside 1, the median over the ``compare`` (H, W) bool pixels of
    the face's level (the channels' sum, ``face`` (H, W, 3)) over the source's (``part``).

    The range is for two people's skin under two lights; a clip's exposure is not a person's.
    Onto a dark target (walk52's ``dark.mp4``, every level times 0.12) the gain the mouth
    needs is ~0.15, and clipped at 0.4 the source's mouth was pasted at 2-3 times the face's
    level, a bright mouth on a dark face. Now the low end is ``0.4 e`` for an exposure ``e``
    below 1, the high ``2.5 e`` above it: the range about the exposure, as it was about 1.
    """
    lo, hi = MOUTH_GAIN_RANGE
    at = np.flatnonzero(compare)
    if not at.size:
        return lo, hi
    f, p = (_level(x.reshape(-1, 3), at) for x in (face, part))
    e = float(np.median(f / p))
    return lo * min(e, 1.0), hi * max(e, 1.0)


def _level(pixels: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The channels' sum plus 3 of ``pixels[at]`` ((n, 3) uint8), float32 (the channels
    added in their order: half the time of a gather's ``sum(axis=-1)``, the same floats)."""
    g = pixels.take(at, axis=0)
    return g[:, 0].astype(np.float32) + g[:, 1] + g[:, 2] + np.float32(3.0)


def _membrane_mouth(T: np.ndarray, face_img: np.ndarray, face_mask: np.ndarray,
                    mouth_img: np.ndarray, mask: np.ndarray, feather: float) -> np.ndarray:
    """``face_img`` with the source's mouth blended in where ``mask`` (H, W) bool: the pixels
    of ``membrane_blend(over(T, face_img, face_mask), mouth_img, mask, outlier=None)`` inside
    the face (every outline pixel counts: skin tones of two people are expected to differ),
    computed on the crop that blend works on and written into ``face_img`` in place."""
    sub = membrane_crop(mask)
    if sub is None:
        return face_img
    base = over(T[sub], face_img[sub], face_mask[sub])
    face_img[sub] = membrane_blend(base, mouth_img[sub], mask[sub], feather=feather,
                                   outlier=None)
    return face_img


def mouth_ring_faces(topo: MeshTopology, *, rings: int = MOUTH_RING) -> np.ndarray:
    """The ``rings`` rings of triangles around ``topo.mouth_faces`` (not those), ``(F',) bool``:
    the skin whose colours in the source's frame and in the face set the mouth's gain."""
    sel = np.zeros(len(topo.faces), bool)
    sel[np.asarray(topo.mouth_faces, np.int64)] = True
    return faces_around(topo.faces, sel, rings=rings)
