"""The browser dial editor: one self-contained HTML page (no network) to look at a model or a track.

``facetransfer view MODEL.npz|TRACK.npz --out page.html`` writes a page with the pinned three.js
build inlined (package data ``data/vendor/three/``, see its README for the version and how to
update it), the face's mesh and morph targets embedded (int16, one scale per target), and

* a slider per expression shape (the 52 ARKit blendshapes for an ARKit model, else one per
  training row of each mode but the identity: a trilinear model's expressions and visemes),
* a slider per semantic identity dial (:mod:`facetransfer.dials`),
* head yaw, pitch and roll (head angles in degrees: ``R = Ry(yaw) Rx(pitch) Rz(roll)``,
  three.js's ``"YXZ"`` order, the signs of :func:`facetransfer.export.common.head_euler`),
* for a track: a timeline with play and pause that drives the shapes and head pose per frame,
* an eyeball behind each eye hole (:func:`eye_data`: the tracker's gaze model, turned by the
  eyeLook* sliders as :func:`facetransfer.track.gaze.activation_gaze` reads them; a Live Link
  Face take's by its recorded eye angles, :func:`_frame_gaze`), and a dark
  cone behind the mouth gap and each eye hole (:func:`cavity_loops`) with the skin's back faces
  dark, so that the parted lips and the eye corners show the head's inside, not the page.

Identity dials act on the neutral face (their offsets are exact there); the expression offsets
stay those of the shown identity (the bilinear cross term is left out in the page).

The page reads ``#name=value&...`` from its URL (slider ids, ``frame=K``, ``play``) so that a
view can be linked, and so the tests can drive it from headless Chromium. ``K`` is the frame's
number (:mod:`facetransfer.io.frame_numbers`: a plate's as its files, ``frame=1004`` of a
plate from 1001; a video's row from 0), as the page's counter, its own address and its saved
face's ``frame`` name it; an older page's address kept the row, which is read as such where
it is below the plate's first number, so none of its frames (``frame=3`` of a plate from 1001;
``frame=500`` of one of 1500 frames from 1001, before read as its first frame). A number that
is both a row and one of the plate's (``frame=3`` of a plate from 1) is the plate's.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..io.atomic import write_text_atomic
from ..palette import TEETH_SPAN
from ..puppet_face import CAVITY_BACK, IRIS_RIM, LID_PAIRS, LID_SHADE, PALETTE, TEETH_SHOW
from ..puppet_face import SHUT_MARGIN, blink_shapes
from ..puppet_face import IRIS_RADIUS as _IRIS_RADIUS, PUPIL_RADIUS as _PUPIL_RADIUS
from ..track.gaze import EYE_RADIUS as _EYE_RADIUS
from ..track.lip_contact import LIP_PAIRS
from .common import ExportError, head_quaternions, require_activations, source_name

log = logging.getLogger(__name__)

__all__ = ["THREE_VERSION", "THREE_SHA256", "viewer_page", "write_viewer", "view_rig", "eye_data",
           "page_palette", "cavity_cone", "loop_cones"]

#: The vendored three.js release and the sha256 of its ``build/three.min.js``.
THREE_VERSION = "0.159.0"
THREE_SHA256 = "7b1c5d75b28d9de15042e2b374f83566d8c7146697af8fdeb4558b0fb528a585"


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def _quantize(targets: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """``(T, n, 3)`` float -> int16 and one scale per target (max |offset| / 32767)."""
    m = np.abs(targets).reshape(len(targets), -1).max(axis=1)
    scale = np.where(m > 0, m / 32767.0, 1.0)
    q = np.round(targets / scale[:, None, None]).astype(np.int16)
    return q, [float(s) for s in scale]


def _training_shapes(model, identity: np.ndarray, mode: str):
    """A model without ARKit shapes: its neutral face (every other mode at
    :func:`facetransfer.dials.neutral_weights`'s) and a slider per training row of every mode
    but the identity (but a ``neutral`` row): the offset of that row's face. The expression
    mode's (:func:`_shape_kind`) are named by their labels, another mode's ``MODE:LABEL``
    (a trilinear model's visemes: ``viseme:eel``), as :mod:`facetransfer.face_file` reads
    them."""
    from ..dials import neutral_weights

    main = _shape_kind(model)
    rest = neutral_weights(model, mode)
    neutral = model.synthesize({**rest, mode: identity})
    names, offsets = [], []
    for k, name in enumerate(model.mode_names):
        if name == mode:
            continue
        for lab in (lab for lab in model.labels[k] if lab != "neutral"):
            offsets.append(model.synthesize({**rest, mode: identity,
                                             name: model.training_weights(k, lab)}) - neutral)
            names.append(lab if name == main else f"{name}:{lab}")
    modes = [n for n in model.mode_names if n != mode]
    title = f"{' and '.join(modes)} (training shapes)"
    return (neutral, np.stack(offsets) if offsets else np.zeros((0,) + neutral.shape), names,
            title)


def view_rig(model, identity: np.ndarray, dials=None):
    """Neutral ``(n, 3)``, shape offsets ``(S, n, 3)`` with their names and title, and identity
    dial offsets of the neutral ``(K, n, 3)`` for the page."""
    from ..arkit import ARKIT_NAMES, expression_rig, is_arkit_model
    from ..dials import neutral_weights

    mode = dials.mode if dials is not None else "identity"
    if is_arkit_model(model):
        rig = expression_rig(model, {mode: identity})
        neutral, shapes, names, title = rig.neutral, rig.deltas, list(ARKIT_NAMES), \
            "ARKit blendshapes"
    else:
        neutral, shapes, names, title = _training_shapes(model, identity, mode)
    dial_off = np.zeros((0,) + neutral.shape)
    if dials is not None and dials.dials:
        rest = neutral_weights(model, mode)
        base = model.synthesize({**rest, mode: identity})
        moved = model.synthesize({**{n: np.tile(v, (len(dials.dials), 1)) for n, v in rest.items()},
                                  mode: identity + np.stack([d.direction for d in dials.dials])})
        dial_off = moved - base
    return neutral, shapes, names, title, dial_off


def page_palette() -> dict:
    """The page's colours: :data:`facetransfer.puppet_face.PALETTE` (the puppet's: one palette
    for both previews) as CSS ``#rrggbb``, with ``cavity_back`` and ``iris_rim``
    (:data:`facetransfer.puppet_face.CAVITY_BACK`, ``IRIS_RIM``). The page paints its skin,
    its eyeballs' canvas (sclera, iris to ``iris_rim`` then toward ``limbus``, pupil), the
    mouth's and the eye sockets' insides (``cavity`` at the mouth, ``cavity_back`` of it at the
    cones' apexes, in the sockets and on the skin's back faces) and the upper teeth (``teeth``,
    in :data:`facetransfer.puppet_face.TEETH_SHOW`'s band, as the puppet's; none while the lips
    are shut, :data:`TEETH_GAP`) with them."""
    out = {k: "#%02x%02x%02x" % tuple(v) for k, v in PALETTE.items()}
    return {**out, "cavity_back": CAVITY_BACK, "iris_rim": IRIS_RIM}


#: Half-angles (degrees, about the eyeball's centre from its gaze axis) of the iris and the pupil:
#: the puppet's (:data:`facetransfer.puppet_face.IRIS_RADIUS`, ``PUPIL_RADIUS``: an 11.8 mm
#: iris and a 4 mm pupil) on an eyeball of :data:`facetransfer.track.gaze.EYE_RADIUS`.
IRIS_ANGLE, PUPIL_ANGLE = (float(np.degrees(np.arcsin(r / _EYE_RADIUS)))
                           for r in (_IRIS_RADIUS, _PUPIL_RADIUS))


def eye_data(model, neutral: np.ndarray, names: list,
             shapes: np.ndarray | None = None) -> dict | None:
    """What the page needs to draw and turn the eyeballs; None for a model without landmarks.

    Each eyeball is :func:`facetransfer.track.gaze.eye_model`'s: a sphere about the eye's centre
    of rotation through the iris centre (the iris on its pole). That model scales with the eye's
    width, so it goes to the page as ``centre = (o + i) / 2 + |o - i| offset`` and ``radius =
    |o - i| ratio`` of the eye's outer and inner corner vertices ``o``, ``i`` (``offset`` and
    ``ratio`` read from ``eye_model`` of ``neutral``): the page places the eyeballs for the
    identity its dials show. Expressions leave them where they are (a blink moves the lids, not
    the eyeball). The mesh's lids do not quite meet at ``eyeBlink`` 1, so the page shades each
    eyeball by its lid gap (:data:`facetransfer.puppet_face.LID_SHADE`, as the puppet does): a
    closing lid darkens the eye, a closed one hides it. Closed: at and under the face's shut
    gap, :func:`facetransfer.puppet_face.shut_gaps_at_blink` of its face at both eyeBlinks 1
    (the puppet's and the exported glb's and USD's rule), which the page computes for the
    identity its dials show: the neutral and dials it draws plus ``blink``, both eyeBlink
    shapes' offsets at the lid and corner vertices, in float64 (the page's morph targets are
    int16: 1e-5 eye widths off on the test model).

    The turn is :func:`facetransfer.track.gaze.activation_gaze`, which is linear in the
    activations: ``gaze`` lists, per expression slider that turns an eye, ``[slider, eye, yaw,
    pitch]``, the angles (radians) of ``activation_gaze`` of that slider at 1 alone; the page sums
    them per eye and turns the eyeball's pole (+z) to
    :func:`facetransfer.track.gaze.gaze_direction` of the sums (``Euler(-pitch, yaw, 0, "YXZ")``).

    Parameters
    ----------
    model : MultilinearModel
    neutral : (n_vertices, 3) float
        The page's neutral face.
    names : list of str
        The page's expression sliders: only ARKit's 52 turn the eyes.
    shapes : (len(names), n_vertices, 3) float, optional
        The sliders' offsets (the eyeBlinks' give ``blink``).

    Returns
    -------
    dict or None
        ``corners`` (2, 2) vertex ids, ``offset`` (2, 3), ``ratio`` (2,), ``gaze`` (G, 4),
        ``lids`` (2, 2, 2) vertex ids (:data:`facetransfer.puppet_face.LID_PAIRS`) and
        ``lid_shade`` (:data:`facetransfer.puppet_face.LID_SHADE`), ``shut_margin``
        (:data:`facetransfer.puppet_face.SHUT_MARGIN`), ``blink`` (vertex id -> (3,), or None
        without both of ARKit's eyeBlinks, :func:`facetransfer.puppet_face.blink_shapes`:
        the shut gap is then ``lid_shade[0]``), ``iris_angle`` and ``pupil_angle`` (degrees;
        the colours are :func:`page_palette`'s); eyes in
        :data:`facetransfer.track.gaze.EYES` order (the subject's right, then left). None also
        where an eye's corners coincide (a degenerate face).
    """
    from ..arkit import ARKIT_NAMES
    from ..track.gaze import CORNER_INDEX, activation_gaze, eye_model

    if model.landmarks is None:
        return None
    lm = np.asarray(model.landmarks, np.int64)
    V = np.asarray(neutral, np.float64)
    eyes = eye_model(V[lm])
    corners = [(int(lm[o]), int(lm[i])) for o, i in CORNER_INDEX]
    width = np.array([np.linalg.norm(V[o] - V[i]) for o, i in corners])
    if not np.all(width > 0):          # a degenerate face (e.g. all-zero weights): no eyeballs
        log.info("no eyeballs: the eye corners coincide (widths %s)", width)
        return None
    mid = np.array([(V[o] + V[i]) / 2 for o, i in corners])
    gaze = []
    if list(names) == list(ARKIT_NAMES):
        unit = activation_gaze(np.eye(len(names)))                 # (52, eye, (yaw, pitch))
        for j, e in zip(*np.nonzero(np.abs(unit).sum(axis=2))):
            gaze.append([int(j), int(e), float(unit[j, e, 0]), float(unit[j, e, 1])])
    lids = [[[int(lm[u]), int(lm[lo])] for u, lo in pairs] for pairs in LID_PAIRS]
    blink, j = None, blink_shapes(model) if list(names) == list(ARKIT_NAMES) else None
    if shapes is not None and j is not None:  # no eyeBlinks (blink_shapes): lid_shade[0]
        ids = sorted({k for pairs in lids for pair in pairs for k in pair} |
                     {k for c in corners for k in c})
        moved = np.asarray(shapes, np.float64)[j][:, ids].sum(axis=0)
        blink = {str(k): [float(x) for x in d] for k, d in zip(ids, moved)}
    return {"corners": [list(c) for c in corners], "lids": lids, "lid_shade": list(LID_SHADE),
            "shut_margin": SHUT_MARGIN, "blink": blink,
            "offset": ((eyes.centre - mid) / width[:, None]).tolist(),
            "ratio": (eyes.radius / width).tolist(), "gaze": gaze,
            "iris_angle": IRIS_ANGLE, "pupil_angle": PUPIL_ANGLE}


#: How far behind its hole each cavity's apex lies, in widths (x extent) of the hole: the mouth
#: bag (3.2 cm behind the inner lips of the ICT face) and the eye sockets (6.0 cm behind the lid
#: margins; the eyeballs' centres sit 0.7 cm behind them, radius 1.04 cm). The sockets' apex was
#: 1.2 widths (2.9 cm): the cone's walls then passed in front of an open eyeball at its corners,
#: 1.4 % of its picture from the front (0.025 cm² an eye, 3 % from 20° above or below); at 2.5,
#: 0.3 %, and no cone point shows but through its eye hole from the front, 30° above or below,
#: ±45° or ±90° (BENCHMARKS.md, fifty-sixth session, review56a).
CAVITY_DEPTH = {"mouth": 0.7, "eye": 2.5}


def cavity_loops(model) -> list[tuple[np.ndarray, float]]:
    """The mouth gap and eye holes of the mesh (:func:`facetransfer.topology.mesh_topology`),
    each with its :data:`CAVITY_DEPTH`: the page closes each with a dark cone to a point behind it
    (:func:`_closed`), the mouth's inside and the eye sockets. Without them the page showed its
    background there: the ICT head is open behind the ears, so nothing stood behind the holes."""
    from ..topology import mesh_topology

    topo = mesh_topology(model)
    return ([(topo.mouth_loop, CAVITY_DEPTH["mouth"])] if topo.mouth_loop.size else []) + \
        [(lp, CAVITY_DEPTH["eye"]) for lp in topo.eye_loops]


#: The inner lips' gap (the mean of iBUG-68's 61-67, 62-66 and 63-65, over the mouth corners'
#: 48-54 distance, in the head's frame) below which the page's mouth is shut and shows no teeth:
#: the page's stand-in for the puppet's :data:`facetransfer.puppet_face.SHUT` (a count of the
#: pixels the lips leave of the mouth's fill, which the page does not have). On ict-arkit faces
#: (the default model's mean person, its id01, id05 and id10, the tests' 6-identity mean; jawOpen
#: in steps of 0.005) the puppet's lips part at gaps of 0.059 to 0.083; at rest the gap is about
#: 0.02 (review53a).
TEETH_GAP = 0.07


def _mouth_shut(model) -> dict | None:
    """What the page needs to tell a shut mouth (:data:`TEETH_GAP`): the inner lips' vertex
    pairs and the mouth corners' vertices; None for a model without landmarks (the puppet's
    mouth is then never shut)."""
    if model.landmarks is None:
        return None
    lm = np.asarray(model.landmarks, np.int64)
    return {"lips": [[int(lm[u]), int(lm[lo])] for u, lo in LIP_PAIRS],
            "corners": [int(lm[48]), int(lm[54])], "gap": TEETH_GAP}


def _mouth_faces(loops: list) -> int:
    """How many of the cavities' faces (:func:`_closed`, after the skin's) are the mouth's (its
    loop comes first in :func:`cavity_loops`, one face a loop vertex): the page paints the
    mouth's lips-side :data:`facetransfer.puppet_face.CAVITY`, darker to its apex as the
    puppet's mouth darkens to its back, and the eye sockets the darker inside."""
    return int(loops[0][0].size) if loops and loops[0][1] == CAVITY_DEPTH["mouth"] else 0


def cavity_cone(points: np.ndarray, loop: np.ndarray, depth: float, apex: int, *offsets):
    """The cone that closes the hole ``loop`` ``(k,)`` of a face ``points`` ``(n, 3)`` (the
    face looks along +z): the mouth's inside and the eye sockets of the `view` page
    (:func:`_closed`), the glb and the USD (:func:`loop_cones`).

    Returns
    -------
    fan : (k, 3) int64
        A triangle per edge of the loop to the vertex ``apex`` (oriented as
        :func:`facetransfer.topology.mesh_topology` closes the mouth: facing out of the face).
    point : (3,) float64
        The apex: behind the mean of the loop's points by ``depth`` times the loop's width (x
        extent).
    moved : each ``(..., 3)``
        Per array of ``offsets`` (``(..., n, 3)``: shape offsets of the face), the apex's: the
        mean of the loop's, so that it follows the lips, or the lids.
    """
    lp = np.asarray(loop, np.int64)
    rim = np.asarray(points, np.float64)[lp]
    fan = np.stack([np.roll(lp, -1), lp, np.full_like(lp, apex)], axis=1)
    point = rim.mean(axis=0) - [0.0, 0.0, depth * np.ptp(rim[:, 0])]
    return (fan, point, *(np.asarray(a)[..., lp, :].mean(axis=-2) for a in offsets))


def loop_cones(neutral: np.ndarray, deltas, loops: list):
    """Cones closing holes of the face ``neutral`` ``(n, 3)``, one triangle set: per ``(loop,
    depth)`` of ``loops`` the `view` page's cone (:func:`cavity_cone`) from the loop's points
    to its apex ``depth`` loop widths behind: the glb's and the USD's mouth inside
    (:func:`facetransfer.export.gltf.mouth_cone`) and eye sockets
    (:func:`facetransfer.export.gltf_eyes.socket_cones`).

    Returns
    -------
    tuple
        ``(points (m, 3) float32, fan (t, 3) int64, [deltas (m, 3) float32 per shape])``: each
        loop's points then its apex, the triangles (facing out of the face), and per shape of
        ``deltas`` (``(S, n, 3)``, the face's) the loops' own deltas and their means for the
        apexes: so each rim is the hole's boundary at any weights in a linear morph evaluator.
    """
    D = np.asarray(deltas)
    points, fans, moved = [], [], []
    for lp, depth in loops:
        rim, base, on_rim = (np.asarray(neutral, np.float64)[lp], sum(len(p) for p in points),
                             D[:, lp])
        fan, apex, d = cavity_cone(rim, np.arange(len(lp)), depth, len(lp), on_rim)
        points += [rim, apex[None]]
        fans.append(fan + base)
        moved.append(np.concatenate([on_rim, d[:, None]], axis=1))
    return (np.concatenate(points).astype(np.float32), np.concatenate(fans),
            list(np.concatenate(moved, axis=1).astype(np.float32)))


def _closed(loops: list, faces: np.ndarray, neutral: np.ndarray, *offsets: np.ndarray):
    """``faces``, ``neutral`` (n, 3) and each of ``offsets`` (``(S, n, 3)``: shape offsets) with
    the apex of :func:`cavity_cone` per ``(loop, depth)`` of ``loops`` appended and its fan."""
    n = neutral.shape[0]
    cones = [cavity_cone(neutral, lp, d, n + j, *offsets) for j, (lp, d) in enumerate(loops)]
    out = [np.concatenate([a] + [c[2 + i][..., None, :] for c in cones], axis=-2)
           for i, a in enumerate(offsets)]
    return (np.concatenate([np.asarray(faces, np.int64), *(c[0] for c in cones)]),
            np.concatenate([neutral, np.reshape([c[1] for c in cones], (-1, 3))]), *out)


def _frame_gaze(track, activations: np.ndarray) -> str | None:
    """The track's gaze (:func:`facetransfer.puppet_face.track_gaze`, as the puppet turns its
    eyes), ``(F, 2, 2)`` float32 base64, where it is not what the page's eyeLook* sliders give
    (:func:`facetransfer.track.gaze.activation_gaze` of ``activations``, the page's timeline):
    a Live Link Face take's recorded eye angles. The page shows them at a frame and adds what
    the eyeLook* sliders are moved by from it. None: the sliders' angles are the track's."""
    from ..puppet_face import track_gaze
    from ..track.gaze import activation_gaze

    g = track_gaze(track)
    if g is None or np.allclose(g, activation_gaze(activations), rtol=0.0, atol=1e-6):
        return None
    return _b64(g.astype(np.float32))


def _shape_kind(model) -> str:
    """What the page's expression sliders are: ``"arkit"``, or the mode of the training
    expressions :func:`view_rig` gives a slider each."""
    from ..arkit import is_arkit_model

    if is_arkit_model(model):
        return "arkit"
    return "expression" if "expression" in model.mode_names else model.mode_names[1]


def _save_data(model, track, mode: str, identity: np.ndarray, title: str) -> dict:
    """What the page's "Save face" writes besides its sliders (:mod:`facetransfer.face_file`):
    the model's hash, the identity of each shot (``shot_starts``; one for a model's page: the
    mean), what the expression sliders are, and the page's source."""
    starts = [0] + ([int(a) for a in track.shot_starts] if track is not None else [])
    ids = [identity] if track is None else [track.weights[mode][a] for a in starts]
    return {"model_hash": model.content_hash, "shot_starts": starts,
            "identities": [[float(v) for v in w] for w in ids],
            "shape_kind": _shape_kind(model), "source": title}


def _about(model, track) -> str:
    """The page's line on what it shows: the model's mean person, a track of its clip, or a
    Live Link Face take (its source a ``.csv``; it said "track of take.csv")."""
    if track is None:
        return f"{model.n_vertices} vertices; three.js {THREE_VERSION}; the model's mean identity"
    name = source_name(track.source)
    shown = f"take {name}" if name.lower().endswith(".csv") else f"track of {name or 'a clip'}"
    shots = (f"; {len(track.shot_starts) + 1} shots: the face drawn is the first one's person, "
             "Save face keeps the shown frame's" if len(track.shot_starts) else "")
    return (f"{model.n_vertices} vertices; three.js {THREE_VERSION}; {shown}, "
            f"{track.n_frames} frames at {track.fps:g} fps{shots}")


def viewer_page(model, *, track=None, title: str = "facetransfer") -> str:
    """The HTML page (a str) for ``model``, or for ``track`` of that model."""
    from ..dials import DialError, learn_dials
    from ..io.frame_numbers import track_first_number

    try:
        dials = learn_dials(model)
    except DialError as exc:  # e.g. fewer than 3 identities: the page shows no dials
        log.info("no identity dials: %s", exc)
        dials = None
    mode = dials.mode if dials is not None else "identity"
    k = model.mode_index(mode) if mode in model.mode_names else 0
    identity = (track.weights_at(0)[model.mode_names[k]] if track is not None
                else model.weight_mean(k))
    neutral, shapes, names, shape_title, dial_off = view_rig(model, identity, dials)
    eyes = eye_data(model, neutral, names, shapes)
    loops = cavity_loops(model)
    faces, neutral, shapes, dial_off = _closed(loops, model.faces, neutral, shapes, dial_off)
    dial_names = list(dials.names) if dials is not None else []
    q, scales = _quantize(np.concatenate([shapes, dial_off]) if len(shapes) + len(dial_off)
                          else np.zeros((0,) + neutral.shape))
    data = {"positions": _b64(neutral.astype(np.float32)),
            "faces": _b64(faces.astype(np.uint32)), "n_skin_faces": len(model.faces),
            "targets": _b64(q), "target_scales": scales, "target_names": names + dial_names,
            "n_shapes": len(names), "shape_title": shape_title,
            "dial_info": [f"{d.effect:+.2f} {dials.unit}/unit, R2 {d.r2_loo:.2f}"
                          for d in dials.dials] if dials is not None else [],
            "n_frames": 0, "fps": 25.0, "eyes": eyes, "palette": page_palette(),
            "n_cavities": len(loops), "n_mouth_faces": _mouth_faces(loops),
            "mouth_loop": loops[0][0].tolist() if _mouth_faces(loops) else [],
            "teeth_show": TEETH_SHOW, "teeth_span": TEETH_SPAN,
            "mouth_shut": _mouth_shut(model),
            **_save_data(model, track, model.mode_names[k], identity, title),
            "about": _about(model, track)}
    if track is not None:
        if len(names) != 52:
            from ..arkit import arkit_shortfall

            raise ExportError(f"track {track.label}: its timeline plays ARKit activations, and "
                              f"{arkit_shortfall(model) or 'the model has none'} (`view` of the "
                              "model itself has a slider per training expression)")
        acts = require_activations(track)
        data.update(n_frames=track.n_frames, fps=track.fps,
                    first_frame=track_first_number(track),    # a plate's: its numbers shown
                    activations=_b64(acts.astype(np.float32)), frame_gaze=_frame_gaze(track, acts),
                    quaternions=_b64(head_quaternions(track.rotation).astype(np.float32)))
    three = resources.files("facetransfer.data").joinpath("vendor/three/three.min.js").read_text()
    template = resources.files("facetransfer.data").joinpath("viewer.html").read_text()
    page = template.replace("__TITLE__", html.escape(title))
    page = page.replace("__DATA__", json.dumps(data).replace("<", "\\u003c"))
    return page.replace("<script>__THREE__</script>", f"<script>{three}</script>", 1)


def write_viewer(source: str | os.PathLike, out: str | os.PathLike, *, model=None,
                 overwrite: bool = False, neutral=None) -> Path:
    """Write the page for ``source`` (a model ``.npz`` or a ``TRACK.npz``) and return its path.

    Parameters
    ----------
    source : path-like
        A model file or a track file (told apart by their contents).
    model : MultilinearModel, optional
        For a track: its model (default: the default model, if the track was made with it).
    neutral : int or "auto", optional
        For a track: its activations measured from this frame's
        (:mod:`facetransfer.export.neutral`); a model has none.
    """
    from ..errors import ModelFileError
    from ..model import load_model
    from ..track import Track
    from .common import resolve_model

    from ..io.npz import (NOT_ARCHIVE_ERRORS, NOT_NPZ, archive_names, check_input_file,
                          content_kind, reason)

    src = check_input_file(source, "model or track file", ExportError)
    try:
        names = archive_names(src)
    except NOT_ARCHIVE_ERRORS as exc:
        kind = content_kind(src)        # another kind of file: named (a .glb, a take, ...)
        raise ExportError(f"{src} is neither a model nor a track file" + (
            f": it is {kind}" if kind not in (None, NOT_NPZ) else
            f" (truncated or not an .npz archive: {reason(exc)})")) from None
    if names is None:    # an .npy array named .npz
        raise ExportError(f"{src} is neither a model nor a track file: it is an .npy array, "
                          "not an .npz archive")
    is_track = {"rotation", "mode_names"} <= names
    if neutral is not None and not is_track:
        raise ExportError(f"--neutral is for a track; {src} is a model")
    if is_track:
        from .neutral import with_neutral

        track = with_neutral(Track.load(src), neutral)
        page = viewer_page(resolve_model(track, model), track=track, title=src.name)
    else:
        try:
            m = load_model(src)
        except ModelFileError as exc:
            raise ExportError(f"{src} is neither a model nor a track file ({exc})") from None
        page = viewer_page(m, title=src.name)
    return write_text_atomic(out, page, overwrite=overwrite)
