"""The puppet's eyes and mouth (facetransfer.puppet_face through puppet_video.puppet_frames):
eyeballs that look where the track's eyeLook* activations look, hidden by a blink, and a dark
cavity in an open mouth. Before, the eye holes and the mouth gap were closed in the skin's
colour."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.puppet_video import puppet_frames

from conftest import mean_person_track

SIZE = 256


def _track(activations: np.ndarray, model):
    """A frontal track of ``model``'s mean person, the face whole in the frame (12 px per cm:
    an eye 32 px wide)."""
    return mean_person_track(model, activations, size=SIZE, scale=12.0)


def _acts(**values: float) -> np.ndarray:
    """One frame's 52 ARKit activations: ``values`` by name, the others 0."""
    a = np.zeros((1, 52), np.float32)
    for name, v in values.items():
        a[0, ARKIT_NAMES.index(name)] = v
    return a


def _render(model, track) -> np.ndarray:
    """The puppet (the model's mean person) of ``track``'s first frame."""
    return next(puppet_frames(track, model, model.weight_mean("identity")))


def _box(model, track, points, pad: int = 4) -> tuple[slice, slice]:
    """The image box (rows, columns) around the frame's landmarks ``points`` (iBUG-68)."""
    V = model.synthesize(track.weights_at(0))
    P = track.camera(0).project(V[np.asarray(model.landmarks)[list(points)]])
    (x0, y0), (x1, y1) = np.floor(P.min(0)) - pad, np.ceil(P.max(0)) + pad
    return slice(int(y0), int(y1) + 1), slice(int(x0), int(x1) + 1)


def _ratios(px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R, G / R and B / R of pixels (n, 3): the skin's shading keeps its G / R (0.83) and
    B / R (0.73); an eye's white, an iris or a mouth's cavity have other ratios."""
    p = px.reshape(-1, 3).astype(np.float64)
    r = np.maximum(p[:, 0], 1.0)
    return p[:, 0], p[:, 1] / r, p[:, 2] / r


def _sclera(px):
    """An off-white: bright, near grey."""
    r, g, b = _ratios(px)
    return (r > 120) & (g > 0.9) & (b > 0.88)


def _iris(px):
    """Brown to black: an iris (a brown's G / R under the skin's, B / R well under) or its
    pupil."""
    r, g, b = _ratios(px)
    return ((g < 0.78) & (g > 0.55) & (b < 0.6)) | (r < 30)


def _cavity(px):
    """A dark red-brown: red well above green and blue."""
    r, g, b = _ratios(px)
    return (r < 130) & (r > 20) & (g < 0.5) & (b < 0.5)


LEFT_EYE, RIGHT_EYE, MOUTH = range(42, 48), range(36, 42), range(48, 68)


def test_open_eyes_show_a_sclera_and_an_iris_a_blink_shows_neither(arkit_model):
    """Open eyes: each eye's box holds off-white and brown pixels (before: skin only); a full
    blink (eyeBlinkLeft = eyeBlinkRight = 1): the lids cover the eyeballs, none; a half blink
    shows less iris than open eyes, but some."""
    counts = {}
    for blink in (0.0, 0.5, 1.0):
        track = _track(_acts(eyeBlinkLeft=blink, eyeBlinkRight=blink), arkit_model)
        img = _render(arkit_model, track)
        counts[blink] = []
        for eye in (RIGHT_EYE, LEFT_EYE):
            px = img[_box(arkit_model, track, eye)]
            counts[blink].append((int(_sclera(px).sum()), int(_iris(px).sum())))
    for sclera, iris in counts[0.0]:
        assert sclera > 40 and iris > 40, counts
    assert counts[1.0] == [(0, 0), (0, 0)], counts
    for (_, half), (_, open_) in zip(counts[0.5], counts[0.0]):
        assert 0 < half < open_, counts


def _iris_centre(img, box) -> np.ndarray:
    """(x, y) centroid of the iris-coloured pixels in ``box``."""
    m = _iris(img[box]).reshape(img[box].shape[:2])
    ys, xs = np.nonzero(m)
    assert ys.size > 20
    return np.array([xs.mean() + box[1].start, ys.mean() + box[0].start])


@pytest.mark.parametrize("look, sign", [("eyeLookOutLeft", 1.0), ("eyeLookInLeft", -1.0)])
def test_eye_look_turns_the_left_eye_its_way(arkit_model, look, sign):
    """eyeLookOutLeft = 1 turns the subject's LEFT eye toward its left ear: for a frontal face
    image right (the model's +x, :mod:`facetransfer.track.gaze`), by several pixels
    (35 degrees of a ball 13 px in radius: ~7 px); eyeLookInLeft = 1 toward the nose (image
    left). The right eye stays (before: no iris at all)."""
    still = _track(_acts(), arkit_model)
    moved = _track(_acts(**{look: 1.0}), arkit_model)
    a, b = _render(arkit_model, still), _render(arkit_model, moved)
    left, right = _box(arkit_model, still, LEFT_EYE), _box(arkit_model, still, RIGHT_EYE)
    d = _iris_centre(b, left) - _iris_centre(a, left)
    assert sign * d[0] > 4 and abs(d[1]) < 2, d
    np.testing.assert_allclose(_iris_centre(b, right), _iris_centre(a, right), atol=0.5)


def test_a_track_without_arkit_activations_looks_straight_ahead(arkit_model):
    """A track without eyeLook* activations (a model whose expressions are not ARKit-named):
    the eyeballs look straight ahead, the picture of eyeLook* all 0, eyes shown."""
    track = _track(_acts(eyeLookUpLeft=0.8, eyeLookOutRight=0.6), arkit_model)
    bare = dataclasses.replace(track, blendshapes=None, blendshape_names=None)
    ahead = _track(_acts(), arkit_model)
    img = _render(arkit_model, bare)
    ref = _render(arkit_model, dataclasses.replace(ahead, weights=track.weights))
    for eye in (LEFT_EYE, RIGHT_EYE):
        box = _box(arkit_model, track, eye)
        assert _iris(img[box]).sum() > 40
        np.testing.assert_array_equal(img[box], ref[box])
    assert not np.array_equal(img, _render(arkit_model, track))   # the gaze did turn those


def test_an_open_mouth_shows_a_dark_cavity_a_shut_one_none(arkit_model):
    """jawOpen = 1: dark red-brown pixels between the lips (before: the gap's fan in the skin's
    colour), with the upper teeth's off-white above them; jawOpen = 0 (the mouth shut): none."""
    shut = _track(_acts(), arkit_model)
    wide = _track(_acts(jawOpen=1.0), arkit_model)
    box = _box(arkit_model, wide, MOUTH)
    open_px, shut_px = _render(arkit_model, wide)[box], _render(arkit_model, shut)[box]
    assert _cavity(open_px).sum() > 100
    assert _sclera(open_px).sum() > 5           # the teeth
    assert _cavity(shut_px).sum() == 0 and _sclera(shut_px).sum() == 0


def test_the_render_preview_shows_the_eyes_and_the_mouth(arkit_model_path, tmp_path, capsys):
    """``facetransfer render`` draws the puppet's eyes and mouth (before: the eye holes and an
    open mouth showed the background through the mesh): irises looking where the expression's
    eyeLook* activations say (eyeLookOutLeft: the left eye, image right, looks image right;
    the right eye stays), an open mouth's cavity, none in a neutral mouth."""
    from facetransfer.cli.main import main

    def preview(expression: str) -> np.ndarray:
        from PIL import Image

        out = tmp_path / f"{expression}.png"
        assert main(["render", str(arkit_model_path), "--like", f"expression={expression}",
                     "--size", "256x256", "--background", "40,40,48", "--out", str(out)]) == 0
        capsys.readouterr()
        return np.asarray(Image.open(out).convert("RGB"))

    ahead, look, wide = (preview(e) for e in ("neutral", "eyeLookOutLeft", "jawOpen"))
    for img in (ahead, look):
        for half in (img[:, :128], img[:, 128:]):
            assert _iris(half).sum() > 20
    box = (slice(0, 256), slice(128, 256))   # the subject's left eye, image right
    d = _iris_centre(look, box) - _iris_centre(ahead, box)
    assert d[0] > 2, d
    right = (slice(0, 256), slice(0, 128))
    np.testing.assert_allclose(_iris_centre(look, right), _iris_centre(ahead, right), atol=0.5)
    assert _cavity(wide).sum() > 50 and _cavity(ahead).sum() == 0


#: A take's recorded eye angles (radians; the app's signs, facetransfer.export.livelink's
#: References: yaw + toward the subject's right, pitch + looking down) for
#: :func:`_take_with_eye_columns`: both eyes 0.35 rad (20°) to the subject's left and 0.1 rad
#: down, its eyeLook* curves all 0 (before, a yaw of +0.35 was read as to the subject's left).
RECORDED = {"LeftEyeYaw": -0.35, "LeftEyePitch": 0.1, "RightEyeYaw": -0.35, "RightEyePitch": 0.1}


def _take_with_eye_columns(model, path, n: int = 3, **columns: float):
    """A Live Link Face take of ``n`` rows of the mean person, its eyeLook* all 0 and its eye
    rotation columns set to ``columns`` (as the iPhone records them, apart from its curves)."""
    import csv

    from facetransfer.export.livelink import write_livelink

    write_livelink(mean_person_track(model, np.zeros((n, 52), np.float32)), path)
    rows = list(csv.reader(path.read_text().splitlines()))
    for name, v in columns.items():
        for row in rows[1:]:
            row[rows[0].index(name)] = f"{v:.8f}"
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    return path


def test_a_takes_gaze_is_its_recorded_eye_angles(arkit_model, tmp_path):
    """track_gaze (what the puppet and the view page turn the eyes by) of a take that carries
    its own eye rotation columns is those angles on the take's timeline (pitch + up, as
    track.gaze has it), not activation_gaze of its eyeLook* (0 here: before, the eyes looked
    ahead); a take whose eye columns are 0 (a tool that records none) or a track of a clip is
    activation_gaze of its activations."""
    from facetransfer.puppet_face import track_gaze
    from facetransfer.take import take_track
    from facetransfer.track.gaze import activation_gaze

    mean = arkit_model.weight_mean("identity")
    take = take_track(_take_with_eye_columns(arkit_model, tmp_path / "t.csv", **RECORDED),
                      arkit_model, mean)
    want = np.tile([[0.35, -0.1], [0.35, -0.1]], (take.n_frames, 1, 1))
    np.testing.assert_allclose(track_gaze(take), want, atol=1e-7)
    plain = take_track(_take_with_eye_columns(arkit_model, tmp_path / "z.csv"), arkit_model, mean)
    np.testing.assert_array_equal(track_gaze(plain), np.zeros((plain.n_frames, 2, 2)))
    clip = _track(_acts(eyeLookOutLeft=0.5), arkit_model)
    np.testing.assert_allclose(track_gaze(clip), activation_gaze(clip.blendshapes))


def test_the_puppet_of_a_take_looks_where_the_take_recorded(arkit_model, tmp_path):
    """The puppet turned by track_gaze of a take with recorded eye angles (20° to the subject's
    left, eyeLook* 0): both irises sit right of where they sit looking ahead (image right, the
    subject's left, for the take's frontal head), as puppet_frames draws them (its face's
    gaze the only change)."""
    from facetransfer.puppet_face import paint_face, puppet_face, track_gaze
    from facetransfer.render import render
    from facetransfer.take import take_track
    from facetransfer.topology import close_mouth, mesh_topology

    take = take_track(_take_with_eye_columns(arkit_model, tmp_path / "t.csv", **RECORDED),
                      arkit_model, arkit_model.weight_mean("identity"))
    topo = mesh_topology(arkit_model, lips=False)
    V0 = close_mouth(arkit_model.synthesize(take.weights_at(0)), topo)

    def draw(gaze) -> np.ndarray:
        face = puppet_face(arkit_model, topo, gaze=gaze)
        V = face.vertices(V0)
        out = render(V, face.faces, take.camera(0), take.frame_size,
                     colors=np.broadcast_to(np.array([205.0, 170.0, 150.0]), V.shape))
        paint_face(out.image, out.raster, V, take.camera(0), face, 0)
        return out.image

    ahead, looked = draw(None), draw(track_gaze(take))
    for eye in (LEFT_EYE, RIGHT_EYE):
        box = _box(arkit_model, take, eye)
        d = _iris_centre(looked, box) - _iris_centre(ahead, box)
        assert d[0] > 2, d


def test_puppet_frames_of_a_take_turn_the_eyes_by_its_recorded_angles(arkit_model, tmp_path,
                                                                      monkeypatch):
    """puppet_frames itself (the command's path) turns a take's eyes by its recorded angles:
    both irises right of the same take's with its eye columns 0; and the render cache's key of
    the two takes differs (the angles are in the track's info, which the track's arrays do not
    carry: before, an edit of a take's eye columns alone reused the old puppet)."""
    from facetransfer import render_cache
    from facetransfer.take import take_track

    mean = arkit_model.weight_mean("identity")
    looked = take_track(_take_with_eye_columns(arkit_model, tmp_path / "t.csv", **RECORDED),
                        arkit_model, mean)
    ahead = take_track(_take_with_eye_columns(arkit_model, tmp_path / "z.csv"), arkit_model,
                       mean)
    a, b = (next(puppet_frames(t, arkit_model, mean)) for t in (ahead, looked))
    for eye in (LEFT_EYE, RIGHT_EYE):
        box = _box(arkit_model, looked, eye)
        assert (_iris_centre(b, box) - _iris_centre(a, box))[0] > 2
    monkeypatch.setattr(render_cache, "cache_enabled", lambda: True)
    keys = {render_cache.puppet_key(t, arkit_model, mean, None) for t in (ahead, looked)}
    assert len(keys) == 2


@pytest.mark.parametrize("size", [64, 128])
def test_a_small_puppets_mouth_at_rest_shows_no_teeth_at_any_subpixel_position(arkit_model,
                                                                               size):
    """The mouth at rest (every activation 0) of a small puppet, its head a quarter of a pixel
    apart from frame to frame: shut in every frame, no cavity or teeth (before: the lips'
    sliver, under a pixel high, lit a row of pixels at one position, 5 of a 12 pixel wide
    mouth at 64x64: drawn open, teeth flickering in and out as the head moved); the eyes stay
    open; jawOpen = 0.4 still shows the cavity."""
    scale = size / 25.6

    def frame(dx: float, **values: float) -> np.ndarray:
        t = mean_person_track(arkit_model, _acts(**values), size=size, scale=scale)
        t = dataclasses.replace(t, translation=np.array([[size / 2 + dx, 0.625 * size + dx]]))
        return t, _render(arkit_model, t)

    for dx in (0.0, 0.25, 0.5, 0.75):
        t, img = frame(dx)
        px = img[_box(arkit_model, t, MOUTH, pad=1)]
        assert _cavity(px).sum() == 0 and _sclera(px).sum() == 0, dx
        for eye in (LEFT_EYE, RIGHT_EYE):
            assert _sclera(img[_box(arkit_model, t, eye, pad=1)]).sum() > 0, dx
    t, img = frame(0.0, jawOpen=0.4)
    assert _cavity(img[_box(arkit_model, t, MOUTH, pad=1)]).sum() > 3


def test_closing_lids_darken_the_puppets_eyeball_as_the_pages(arkit_model):
    """eyeBlink* = 0.8 (the lids 0.105 eye widths apart): the eyeball shows through the gap
    darkened by lid_light, the view page's shade of it (0.19 here), so no bright sclera is
    left (before: the sliver's sclera lit as an open eye's, where the page's was dark); open
    eyes stay lit whole (lid_light 1)."""
    from facetransfer.puppet_face import lid_light

    track = _track(_acts(eyeBlinkLeft=0.8, eyeBlinkRight=0.8), arkit_model)
    V = arkit_model.synthesize(track.weights_at(0))
    lit = lid_light(V[np.asarray(arkit_model.landmarks)])
    assert np.all((lit > 0.05) & (lit < 0.4)), lit
    img = _render(arkit_model, track)
    for eye in (RIGHT_EYE, LEFT_EYE):
        px = img[_box(arkit_model, track, eye)]
        assert _sclera(px).sum() == 0
    rest = arkit_model.synthesize(_track(_acts(), arkit_model).weights_at(0))
    np.testing.assert_array_equal(lid_light(rest[np.asarray(arkit_model.landmarks)]), [1, 1])


def test_the_preview_hides_the_shut_eye_of_a_face_whose_lids_stay_apart(arkit_model):
    """pageeyes56: the test model's identity 1 stops its lids 0.098 eye widths apart at
    eyeBlink 1; `render`'s preview (preview_face, draw_face) lit its eyeballs there at 6-9 %
    (lid_light from the fixed 0.08) through the fill the lids leave, where the exports hide
    them. Now the face's own shut gap (puppet_face.face_shut_gaps) shuts them: the fill is the
    lids' line, the preview's grey skin darkened (before: the eyeball's sclera and iris,
    coloured)."""
    from facetransfer.arkit import activations_to_weights
    from facetransfer.puppet_face import preview_face, puppet_face
    from facetransfer.topology import mesh_topology

    w = {"identity": arkit_model.factors[arkit_model.mode_index("identity")][1],
         "expression": activations_to_weights(arkit_model, _acts(eyeBlinkLeft=1.0,
                                                                 eyeBlinkRight=1.0))[0]}
    res = preview_face(arkit_model, w, size=(640, 480))
    kind = puppet_face(arkit_model, mesh_topology(arkit_model, lips=False)).kind
    fill = np.isin(kind[res.raster.tri_id + 1], (0, 1))
    assert fill.sum() > 100                            # the lids leave a fill wider than SHUT
    px = res.image[fill].astype(np.int64)
    assert np.all(px.max(axis=1) == px.min(axis=1))  # the preview's grey skin, no eyeball
