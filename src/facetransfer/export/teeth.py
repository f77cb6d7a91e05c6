"""The teeth of a ``.glb`` and a USD: an upper and a lower row on the dental arches behind the lips.

The exported face (:mod:`.gltf`, :mod:`.usd`) closes its lips' gap with a dark cone (the mouth's
inside); with no teeth a wide jawOpen showed a dark hole in a player, where the `view` page paints
the upper teeth and a rewrite draws both rows (:mod:`facetransfer.mouth_inside`). Here each row is
a curved strip standing on the dental arch that the rewrite draws its teeth on
(:func:`facetransfer.dental.dental_arch` of the file's own neutral face: ``z = front -
ARCH_CURVE x²`` in eye widths, its front :data:`facetransfer.dental.ARCH_BEHIND` behind
that lip's inner edge over the middle of the mouth), set :data:`SET_BACK` farther back, reaching
:data:`REACH` of the mouth's half-width each side of its middle:

- the **upper teeth** hang from :data:`ROOT` eye widths above the upper lip's inner edge (hidden
  behind the lip) to :data:`facetransfer.palette.TEETH_SHOW` below it (the page's band), rigid
  with the head: no shape moves them (the upper jaw is the skull's);
- the **lower teeth** stand from :data:`ROOT` below the lower lip's inner edge to
  :data:`facetransfer.dental.LOWER_SHOW` above it and follow the jaw: for each of
  :data:`JAW_SHAPES` their morph target is the rigid motion (a rotation and a translation,
  least squares: :func:`rigid_fit`) that best carries the chin's vertices (:func:`chin_vertices`)
  to where that shape puts them at activation 1; no other shape moves them. They take the face's
  weights (the glb's one ``weights`` channel; the USD's SkelAnimation, by the shapes' names).

Their colours are the palette's teeth (:data:`facetransfer.palette.PALETTE`) shaded as a rewrite
shades them (:func:`facetransfer.dental.teeth_shade`: darker toward the mouth's corners, parted
at the incisors, canines and premolars; the lower row at
:data:`facetransfer.dental.LOWER_SHADE`), as vertex colours, linear.

Beyond the paper (it renders no mouth's inside; §6 takes the mouth from the source video).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JAW_SHAPES", "ROOT", "REACH", "SET_BACK", "TeethRow", "Teeth", "rigid_fit",
           "row_moves", "chin_vertices", "teeth_of", "gltf_primitives"]

#: The shapes that move the lower teeth (the jaw's); any other leaves them where they are.
JAW_SHAPES = ("jawOpen", "jawLeft", "jawRight", "jawForward")
#: How far each row reaches behind its lip, beyond that lip's inner edge, in eye widths (the
#: roots' side: about 8 mm, hidden by the lip).
ROOT = 0.3
#: The rows reach this fraction of the mouth's half-width (the inner-lip loop's, at rest) each
#: side of its middle, along the arch.
REACH = 0.9
#: The rows stand this much farther behind the lips than the rewrite's arches, in eye widths
#: (2.7 mm): the default model's jawOpen draws the upper lip's sides back over the arch (1 cm
#: from the middle its inner edge moves 0.34 cm back), and rows on the rewrite's arches showed
#: their ends through the far lip's corner seen from 45° (0.1-0.3 % of their points; 1.3 % in a
#: mixed set of shapes); from 0.1 on, none (BENCHMARKS.md, fifty-sixth session, teethx56).
SET_BACK = 0.1
#: Columns of each strip along the arch (besides those at the teeth's parting lines).
COLUMNS = 32
#: glTF's element-array buffer target (indices).
_ELEMENTS = 34963


@dataclass(frozen=True)
class TeethRow:
    """One row of teeth: a strip of quads (two rows of vertices) along a dental arch.

    Attributes
    ----------
    points : (k, 3) float64
        In the face's units and frame; vertex ``2 i`` the root's side of column ``i``,
        ``2 i + 1`` its biting edge.
    tris : (m, 3) int64
        Triangles facing out of the mouth (toward the lips).
    normals : (k, 3) float64
        The arch's unit normals, out of the mouth, horizontal.
    colours : (k, 3) float32
        Linear RGB.
    """

    points: np.ndarray
    tris: np.ndarray
    normals: np.ndarray
    colours: np.ndarray


@dataclass(frozen=True)
class Teeth:
    """The two rows of a face (:func:`teeth_of`).

    Attributes
    ----------
    upper, lower : TeethRow
    fits : dict of str to tuple
        Per name of :data:`JAW_SHAPES` the face has, the jaw's rigid motion at that shape's
        activation 1, ``(R (3, 3), t (3,))`` (:func:`rigid_fit` of the chin's vertices).
    """

    upper: TeethRow
    lower: TeethRow
    fits: dict

    def lower_deltas(self, names) -> list:
        """The lower row's morph targets for each of ``names`` (:func:`row_moves`)."""
        return row_moves(self.lower, self.fits, names)


def row_moves(row: TeethRow, fits: dict, names) -> list:
    """A row's morph targets for each of ``names``: ``(points, normals)`` deltas, each ``(k,
    3)`` float64, ``R p + t - p`` and ``R n - n`` of that name's rigid motion in ``fits``
    (:attr:`Teeth.fits`; zeros for a name it lacks)."""
    P, N = row.points, row.normals
    out = []
    for name in names:
        R, t = fits.get(name, (np.eye(3), np.zeros(3)))
        out.append((P @ R.T + t - P, N @ R.T - N))
    return out


def rigid_fit(P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and translation carrying the points ``P`` (m, 3) nearest to ``Q`` (m, 3)
    in least squares: :func:`facetransfer.correspond.procrustes.similarity_procrustes` without
    scale (Umeyama's closed form, a reflection ruled out).

    Returns
    -------
    R : (3, 3) float64
        A proper rotation.
    t : (3,) float64
        ``Q ≈ P R^T + t``.
    """
    from ..correspond.procrustes import similarity_procrustes

    fit = similarity_procrustes(P, Q, with_scale=False)
    return fit.rotation, fit.translation


def chin_vertices(model, V: np.ndarray, arch) -> np.ndarray:
    """``(m,)`` int64: the face ``V``'s (n, 3) vertices that the jaw carries and the lips do
    not shape: between the lower lip's outer edge (iBUG 57, less a tenth of an eye width) and
    the chin's bottom (iBUG 8), within the mouth's half-width ``arch.half`` of its middle, in
    front of the chin's bottom point less half an eye width (the skin, not a fold behind)."""
    lm = np.asarray(model.landmarks, np.int64)
    lip, chin = V[lm[57]], V[lm[8]]
    keep = ((V[:, 1] < lip[1] - 0.1 * arch.eye) & (V[:, 1] > chin[1])
            & (np.abs(V[:, 0] - arch.middle) < arch.half)
            & (V[:, 2] > chin[2] - 0.5 * arch.eye))
    return np.flatnonzero(keep)


def _row(arch, front: float, root: float, edge: float, shade: float) -> TeethRow:
    """A strip on the arch whose front z is ``front``, from the roots' height ``root`` to the
    biting edge's ``edge`` (the upper row's root above its edge, the lower row's below),
    :data:`REACH` of the mouth's half-width each side, in the palette's teeth shaded as a
    rewrite shades them, times ``shade``."""
    from ..io.exr import srgb_decode
    from ..dental import ARCH_CURVE, PART_WIDTH, TEETH_PARTS, teeth_shade
    from ..palette import PALETTE, TEETH_SPAN

    reach = REACH * arch.half
    parts = arch.eye * np.asarray(TEETH_PARTS)
    parts = np.concatenate([parts + w for w in (-PART_WIDTH * arch.eye, 0.0,
                                                 PART_WIDTH * arch.eye)])
    u = np.unique(np.concatenate([np.linspace(-reach, reach, COLUMNS + 1), parts, -parts]))
    u = u[np.abs(u) <= reach]
    x = arch.middle + u
    z = arch.z(x, front)
    k = len(u)
    P = np.zeros((k, 2, 3))
    P[:, :, 0], P[:, :, 2] = x[:, None], z[:, None]
    P[:, 0, 1], P[:, 1, 1] = root, edge
    N = np.stack([2.0 * ARCH_CURVE * u / arch.eye, np.zeros(k), np.ones(k)], axis=1)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    i = 2 * np.arange(k - 1)
    tris = np.concatenate([np.stack([i, i + 1, i + 2], 1), np.stack([i + 2, i + 1, i + 3], 1)])
    P = P.reshape(-1, 3)
    normal = np.cross(P[tris[:, 1]] - P[tris[:, 0]], P[tris[:, 2]] - P[tris[:, 0]])
    if np.einsum("ij,ij->i", normal, np.repeat(N, 2, axis=0)[tris[:, 0]]).sum() < 0:
        tris = tris[:, ::-1]
    srgb = teeth_shade(np.asarray(PALETTE["teeth"], np.float64), u, TEETH_SPAN * arch.half,
                  arch.eye) * shade
    colours = srgb_decode(np.clip(np.rint(srgb), 0, 255).astype(np.uint8))
    return TeethRow(P, tris.astype(np.int64), np.repeat(N, 2, axis=0),
                    np.repeat(colours, 2, axis=0).astype(np.float32))


def teeth_of(model, neutral: np.ndarray, deltas) -> Teeth | None:
    """The teeth of the face ``neutral`` (n, 3) with the shapes ``deltas`` (each (n, 3), in
    :data:`facetransfer.arkit.ARKIT_NAMES` order), in their units.

    Returns
    -------
    Teeth or None
        None for a model without landmarks or a mouth gap.
    """
    from ..arkit import ARKIT_NAMES
    from ..dental import LOWER_SHADE, LOWER_SHOW, dental_arch
    from ..palette import TEETH_SHOW
    from ..topology import mesh_topology

    topo = mesh_topology(model)
    if model.landmarks is None or topo.mouth_loop.size == 0:
        return None
    V = np.asarray(neutral, np.float64)
    arch = dental_arch(V, topo, np.asarray(model.landmarks, np.int64)[[36, 39, 42, 45]])
    eye = arch.eye
    upper = _row(arch, arch.upper - SET_BACK * eye, arch.upper_edge + ROOT * eye,
                 arch.upper_edge - TEETH_SHOW * eye, 1.0)
    lower = _row(arch, arch.lower - SET_BACK * eye, arch.lower_edge - ROOT * eye,
                 arch.lower_edge + LOWER_SHOW * eye, LOWER_SHADE)
    chin = chin_vertices(model, V, arch)
    fits = {name: rigid_fit(V[chin], V[chin] + np.asarray(d, np.float64)[chin])
            for name, d in zip(ARKIT_NAMES, deltas)
            if name in JAW_SHAPES and chin.size >= 3}
    return Teeth(upper, lower, fits)


def gltf_primitives(gltf, blob, model, V: np.ndarray, deltas: list) -> list:
    """The teeth as two primitives of the glb's face mesh (none without a mouth gap), after
    its mouth's inside: the upper row with its 52 morph targets all zeros, the lower with the
    jaw shapes' rigid motions (``POSITION`` and ``NORMAL``) and zeros for the other shapes (a
    row's zero targets share one pair of accessors without data); ``COLOR_0`` and a white
    material, both sides shown.

    Parameters
    ----------
    gltf : pygltflib.GLTF2
    blob : facetransfer.export.gltf._Blob
    model : MultilinearModel
    V : (n, 3) float
        The face's neutral, as written (metres).
    deltas : list of (n, 3)
        Its 52 morph targets' deltas, as written.
    """
    from pygltflib import Attributes, Material, PbrMetallicRoughness, Primitive

    from ..arkit import ARKIT_NAMES

    teeth = teeth_of(model, V, deltas)
    if teeth is None:
        return []
    gltf.materials.append(Material(name="teeth", doubleSided=True,
                                   pbrMetallicRoughness=PbrMetallicRoughness(
                                       baseColorFactor=[1.0, 1.0, 1.0, 1.0],
                                       metallicFactor=0.0, roughnessFactor=0.4)))
    prims = []
    for row, fits in ((teeth.upper, {}), (teeth.lower, teeth.fits)):
        zero = np.zeros(row.points.shape, np.float32)          # one pair for every still shape
        still = Attributes(POSITION=blob.morph_accessor(zero, bounds=True),
                           NORMAL=blob.morph_accessor(zero))
        targets = [Attributes(POSITION=blob.morph_accessor(D.astype(np.float32), bounds=True),
                              NORMAL=blob.morph_accessor(Nd.astype(np.float32)))
                   if name in fits else still
                   for name, (D, Nd) in zip(ARKIT_NAMES, row_moves(row, fits, ARKIT_NAMES))]
        attrs = Attributes(POSITION=blob.accessor(row.points.astype(np.float32), "VEC3",
                                                  bounds=True),
                           NORMAL=blob.accessor(row.normals.astype(np.float32), "VEC3"),
                           COLOR_0=blob.accessor(row.colours, "VEC3"))
        prims.append(Primitive(attributes=attrs, material=len(gltf.materials) - 1,
                               indices=blob.accessor(row.tris.astype(np.uint32).reshape(-1, 1),
                                                     "SCALAR", target=_ELEMENTS),
                               targets=targets))
    return prims
