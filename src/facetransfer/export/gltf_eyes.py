"""The eyeballs of a ``.glb``: two spheres behind the face's eye holes, turned by its gaze.

The face mesh has holes where the eyes are; a player showed the head's inside through them (the
`view` page and the puppet draw an eyeball there). Each eye is a node, a child of the ``face``
node (so it follows the head), placed where the tracker's gaze model places the eyeball
(:func:`facetransfer.track.gaze.eye_model` of the person's neutral face: behind the eye's
corners, scaled by its width), sharing one mesh: a sphere of radius 1 scaled by the node to the
eyeball's radius, painted in vertex colours (``COLOR_0``) as the page paints it
(:data:`facetransfer.palette.PALETTE`: the pupil and the iris, to the page's angles
:data:`facetransfer.export.viewer.IRIS_ANGLE` and ``PUPIL_ANGLE``, about the sphere's +z, and
the sclera). The animation turns each by its ``rotation`` channel, one key a frame: ``Ry(yaw)
Rx(-pitch)`` of :func:`facetransfer.track.gaze.activation_gaze`'s angles (yaw toward the
subject's left, +x; pitch up, +y), so +z, the pupil, points along
:func:`facetransfer.track.gaze.gaze_direction`; a Live Link Face take's by its recorded eye
angles where it has them, as the puppet and the ``view`` page turn them
(:func:`track_eye_gaze`). The lids (the face's morph targets) close over them, but not
quite: the default model's shut lids leave a slit of about 0.2 cm, through which 0.34-0.37 cm²
of each eyeball showed from the front (BENCHMARKS.md, fifty-fifth session, helpers review55b
and eyelid55). So, as the ``view`` page does (a closed lid hides the eye, a dark socket
behind), each eye hole is closed behind by a dark cone (:func:`socket_cones`, in
:func:`socket_colour`), and each eyeball is hidden while its lids are shut
(:func:`eyes_shown`: the page's lid gap at or under the lower end of
:data:`facetransfer.puppet_face.LID_SHADE`, or under a face's own gap at ``eyeBlink`` 1 where its
lids stop wider apart: :func:`shut_gaps`, the puppet's and the page's rule,
:func:`facetransfer.puppet_face.shut_gaps_at_blink`), a ``scale`` key a frame (STEP) of the
radius or :data:`SHUT_SCALE` of it: the slit of shut lids shows the socket, a dark line. Nodes
``eyeRight`` and ``eyeLeft``: the subject's own, as ARKit names them. The USD export
(:mod:`facetransfer.export.usd`) has the same eyeballs, bound to joints of those names below its
``head`` (their scale in its SkelAnimation), and the same sockets.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EYE_NODES", "SHUT_SCALE", "eye_placement", "eye_rotations",
           "eyeball_mesh", "track_eye_gaze", "shut_gaps", "eyes_shown", "eye_scales",
           "socket_cones", "socket_colour"]

#: The eye nodes' names, in :data:`facetransfer.track.gaze.EYES` order.
EYE_NODES = ("eyeRight", "eyeLeft")
#: An eyeball's scale while its lids are shut, a share of its radius: a point at its centre,
#: behind the socket (not 0, which leaves a player's normal matrix singular).
SHUT_SCALE = 1e-4
#: Rings of the sphere between its poles and vertices about each ring.
_RINGS, _AROUND = 24, 32


def eye_placement(model, neutral: np.ndarray):
    """The eyeballs of the face ``neutral`` ``(n, 3)`` (model units): ``(centres (2, 3),
    radii (2,))`` in :data:`EYE_NODES` order, or None for a model without landmarks."""
    from ..track.gaze import eye_model

    if model.landmarks is None:
        return None
    eyes = eye_model(np.asarray(neutral, np.float64)[np.asarray(model.landmarks, np.int64)])
    return np.asarray(eyes.centre, np.float64), np.asarray(eyes.radius, np.float64)


def eye_rotations(activations: np.ndarray, gaze: np.ndarray | None = None) -> np.ndarray:
    """Each frame's eyeball turns, ``(F, 2, 4)`` quaternions ``(x, y, z, w)`` in
    :data:`EYE_NODES` order: ``Ry(yaw) Rx(-pitch)`` of ``gaze`` (``(F, 2, 2)``, radians,
    :func:`track_eye_gaze`), or where it is None of the gaze the eyeLook* activations
    ``(F, 52)`` say (:func:`facetransfer.track.gaze.activation_gaze`)."""
    from ..track.gaze import activation_gaze

    g = activation_gaze(activations) if gaze is None else np.asarray(gaze, np.float64)
    hy, hp = g[..., 0] / 2.0, -g[..., 1] / 2.0
    # (0, sin hy, 0, cos hy) * (sin hp, 0, 0, cos hp)
    q = np.stack([np.cos(hy) * np.sin(hp), np.sin(hy) * np.cos(hp),
                  -np.sin(hy) * np.sin(hp), np.cos(hy) * np.cos(hp)], -1)
    return q


def track_eye_gaze(track, activations: np.ndarray) -> np.ndarray:
    """Where the exported eyes look, ``(F, 2, 2)`` ``[frame, eye (right, left), (yaw,
    pitch)]``: as the puppet and the ``view`` page turn them
    (:func:`facetransfer.puppet_face.track_gaze`: a Live Link Face take's recorded eye angles
    where it has them), else the gaze of ``activations`` (``(F, 52)``, the exported curves).
    Before, a take's glb and USD turned the eyes by its eyeLook* curves alone, the page and
    the puppet by its recorded angles: one take, two gazes."""
    from ..puppet_face import track_gaze
    from ..track.gaze import activation_gaze

    recorded = track_gaze(track)
    return activation_gaze(activations) if recorded is None else recorded


def shut_gaps(model, rig) -> np.ndarray:
    """``(2,)``, each eye's (:data:`EYE_NODES` order) lid gap at and below which its eyeball is
    hidden: :func:`facetransfer.puppet_face.shut_gaps_at_blink` (the puppet's and the ``view``
    page's rule: the larger of ``LID_SHADE[0]``, 0.08 eye widths, and the face's own gap at
    ``eyeBlink`` 1 plus ``SHUT_MARGIN``, at most ``LID_SHADE[1]``; lids that cross there keep
    0.08) of the rig's landmark vertices at both eyeBlinks 1: a face whose lids stop wider apart
    (the test model's identity 1: 0.098) hides its shut eyes too."""
    from ..puppet_face import LID_SHADE, blink_shapes, shut_gaps_at_blink

    blink = blink_shapes(model)
    if blink is None:  # no eyeBlink to shut the lids with: the fixed 0.08
        return np.full(2, LID_SHADE[0])
    lm = np.asarray(model.landmarks, np.int64)
    D = np.asarray(rig.deltas, np.float64)
    P = np.asarray(rig.neutral, np.float64)[lm] + D[blink][:, lm].sum(axis=0)
    return shut_gaps_at_blink(P)


def eyes_shown(model, rig, activations: np.ndarray) -> np.ndarray:
    """Whether each eyeball is drawn, ``(F, 2) bool`` (:data:`EYE_NODES` order), per frame of
    ``activations`` ``(F, 52)`` on the exported face (``rig``: its neutral and the 52 deltas, as
    a player adds them): its lid gap (:func:`facetransfer.puppet_face.lid_gaps` of the frame's
    iBUG-68 landmark vertices, the ``view`` page's and the puppet's measure) above
    :func:`shut_gaps` (0.08, ``LID_SHADE[0]``, for the default model, whose lids stop 0.066-0.075
    apart at eyeBlink 1; higher for a face whose shut lids stop wider apart). All shown for a
    model without landmarks."""
    from ..puppet_face import lid_gaps

    a = np.asarray(activations, np.float64)
    if model.landmarks is None:
        return np.ones((len(a), 2), bool)
    lm = np.asarray(model.landmarks, np.int64)
    P = np.asarray(rig.neutral, np.float64)[lm] + np.einsum(
        "fj,jlc->flc", a, np.asarray(rig.deltas, np.float64)[:, lm])
    return lid_gaps(P) > shut_gaps(model, rig)


def eye_scales(shown: np.ndarray, radii) -> np.ndarray:
    """The eyes' scale keys ``(F, 2)``: each eye's radius (``radii`` ``(2,)``, in the file's
    units) where ``shown`` ``(F, 2)`` (:func:`eyes_shown`), :data:`SHUT_SCALE` of it where not."""
    return np.where(np.asarray(shown, bool), 1.0, SHUT_SCALE) * np.asarray(radii, np.float64)


def socket_cones(model, neutral: np.ndarray, deltas):
    """The eye sockets, as the ``view`` page closes the eye holes: per eye hole of the mesh
    (:func:`facetransfer.topology.mesh_topology`), a cone from its loop (the lid margins) to a
    point :data:`facetransfer.export.viewer.CAVITY_DEPTH` ``["eye"]`` of its width behind
    (:func:`facetransfer.export.viewer.loop_cones`: its rim's deltas are the loop's own, so it
    follows the lids); None for a mesh without eye holes.

    Parameters
    ----------
    neutral : (n, 3) float
        The exported face.
    deltas : (S, n, 3) float
        Its shapes' offsets.
    """
    from ..topology import mesh_topology
    from .viewer import CAVITY_DEPTH, loop_cones

    loops = [(lp, CAVITY_DEPTH["eye"]) for lp in mesh_topology(model).eye_loops]
    return loop_cones(neutral, deltas, loops) if loops else None


def socket_colour() -> tuple:
    """The sockets' sRGB colour: the ``view`` page's (``cavity_back``: the mouth's cavity colour
    times :data:`facetransfer.palette.CAVITY_BACK`, the head's inside)."""
    from ..palette import CAVITY_BACK, PALETTE

    return tuple(int(round(c * CAVITY_BACK)) for c in PALETTE["cavity"])


def _colour(theta: np.ndarray) -> np.ndarray:
    """Linear RGB of the eyeball at polar angles ``theta`` (radians from +z)."""
    from ..io.exr import srgb_decode
    from ..palette import PALETTE
    from .viewer import IRIS_ANGLE, PUPIL_ANGLE

    deg = np.degrees(theta)
    name = np.where(deg < PUPIL_ANGLE, "pupil", np.where(deg < IRIS_ANGLE, "iris", "sclera"))
    return srgb_decode(np.array([PALETTE[str(n)] for n in name], np.uint8)).astype(np.float64)


def eyeball_mesh():
    """The unit sphere of an eyeball: ``(positions, colours, indices)``, ``(n, 3) float32``,
    ``(n, 3) float32`` linear RGB, ``(m, 1) uint32`` triangles facing out. The pupil and the
    iris each have their own vertices at their edges, so their colours stop there."""
    from .viewer import IRIS_ANGLE, PUPIL_ANGLE

    edges = np.radians([PUPIL_ANGLE, IRIS_ANGLE])
    bands = [np.linspace(a, b, n + 1) for a, b, n in
             ((0.0, edges[0], 3), (edges[0], edges[1], 4), (edges[1], np.pi, _RINGS))]
    phi = np.arange(_AROUND) * (2 * np.pi / _AROUND)
    pos, col, tris = [], [], []
    for thetas in bands:
        rows = []
        for th in thetas:
            ring = [0.0] if th in (0.0, np.pi) else phi
            rows.append(np.arange(len(ring)) + sum(len(p) for p in pos))
            p = np.stack([np.sin(th) * np.cos(ring), np.sin(th) * np.sin(ring),
                          np.full(len(ring), np.cos(th))], -1)
            pos.append(p)
            col.append(_colour(np.full(len(ring), (thetas[0] + thetas[-1]) / 2)))
        tris += _strips(rows)
    P = np.concatenate(pos)
    T = np.array(tris, np.int64)
    out = np.einsum("ij,ij->i", np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]),
                    P[T].mean(axis=1)) < 0
    T[out] = T[out][:, ::-1]
    return (P.astype(np.float32), np.concatenate(col).astype(np.float32),
            T.astype(np.uint32).reshape(-1, 1))


def _strips(rows: list) -> list:
    """Triangles joining consecutive rows of vertex indices (a row of one: a pole's fan)."""
    tris = []
    for a, b in zip(rows[:-1], rows[1:]):
        n = max(len(a), len(b))
        for j in range(n):
            k = (j + 1) % n
            if len(a) == 1:
                tris.append((a[0], b[j], b[k]))
            elif len(b) == 1:
                tris.append((a[j], a[k], b[0]))
            else:
                tris += [(a[j], a[k], b[k]), (a[j], b[k], b[j])]
    return tris
