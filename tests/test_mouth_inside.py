"""A mouth's inside drawn where the target's own frames never show one
(:mod:`facetransfer.mouth_inside`): a take onto a photo with the lips shut opens onto a dark
cavity and teeth, not the lips' colour stretched; a transfer from a video, and a target that
opens its mouth itself, keep their own."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.arkit import ARKIT_NAMES, MEDIAPIPE_NAMES  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.export.livelink import read_livelink  # noqa: E402
from facetransfer.io.video import read_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402

LUMA = np.array([0.299, 0.587, 0.114])


@pytest.fixture(scope="module")
def einstein_take(data_dir, arkit_model_path, tmp_path_factory):
    """A take ``export``ed from the track of 30 frames of ``driving_d6`` (frames 42-71: the
    jaw shut, then talking) performed by ``stills/einstein.jpg`` (the lips shut under the
    moustache) with the small ARKit model: the folder with ``take.csv``, ``einstein.mp4`` and
    its performance ``new.npz``."""
    from facetransfer.io.video import write_video

    d = tmp_path_factory.mktemp("einstein_take")
    frames, _ = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=72)
    write_video(d / "d6.mp4", frames[42:], 30.0)
    for argv in (["track", d / "d6.mp4", "--out", d / "d6.npz"],
                 ["export", d / "d6.npz", "--out", d / "take.csv"],
                 ["transfer", "--target", data_dir / "stills" / "einstein.jpg",
                  "--expression-from", d / "take.csv", "--out", d / "einstein.mp4",
                  "--save-track", d / "new.npz"]):
        assert main([str(a) for a in argv] + ["--model", str(arkit_model_path),
                                              "--no-progress"]) == 0
    return d


def _face_crops(frames, track):
    """The frames cropped to a square about the first frame's landmarks (Face Landmarker
    finds a small face in a large photo so)."""
    P = track.landmarks2d[0]
    c, s = (P.min(0) + P.max(0)) / 2, np.ptp(P, axis=0).max() * 1.1
    x0, y0 = (max(int(v - s), 0) for v in c)
    return [f[y0:int(c[1] + s), x0:int(c[0] + s)] for f in frames]


def test_face_landmarker_reads_the_takes_jaw_on_a_photo_with_shut_lips(einstein_take):
    """Face Landmarker's jawOpen on the result follows the take's JawOpen curve: r 0.96
    measured; before the inside was drawn 0.78 (the lips' grey stretched across the opening;
    0.79 over 240 frames in the fifty-fourth session's ``take54``)."""
    from facetransfer.fidelity import landmarker_scores

    result, fps = read_video(einstein_take / "einstein.mp4")
    curve = read_livelink(einstein_take / "take.csv").activations[:, ARKIT_NAMES.index("jawOpen")]
    assert len(result) == len(curve) == 30 and np.ptp(curve) > 0.4
    crops = _face_crops(result, Track.load(einstein_take / "new.npz"))
    jaw = landmarker_scores(crops, fps)[0][:, MEDIAPIPE_NAMES.index("jawOpen")]
    assert np.isfinite(jaw).all()
    assert np.corrcoef(jaw, curve)[0, 1] > 0.9


def _mouth_pixels(model, track, frame_index: int):
    """``(fan, lips)`` (H, W) bool of the new face at a frame: the pixels of its mouth's
    opening (the mouth-closing fan, as the render draws it) and of its lips."""
    from facetransfer.mouth import inside_mouth
    from facetransfer.render import rasterize
    from facetransfer.topology import close_mouth, mesh_topology

    topo = mesh_topology(model)
    V = close_mouth(model.synthesize(track.weights_at(frame_index)), topo)
    tid = rasterize(V, topo.faces, track.camera(frame_index), track.frame_size).tri_id
    fan = inside_mouth(tid, topo)
    return fan, np.isin(tid, topo.mouth_faces) & ~fan


def test_the_opened_mouth_shows_a_dark_cavity_and_teeth(einstein_take, arkit_model):
    """At the take's widest jaw the new mouth's opening in the result is dark where the lips
    are grey: its median luminance under 0.6 of the lips' (measured 0.47), and the upper teeth
    show in that dark, its brightest twentieth over twice its median (2.6). Before: the shut
    lips' grey stretched across it (1.05 of the lips; 1.11)."""
    result, _ = read_video(einstein_take / "einstein.mp4")
    curve = read_livelink(einstein_take / "take.csv").activations[:, ARKIT_NAMES.index("jawOpen")]
    k = int(np.argmax(curve))
    fan, lips = _mouth_pixels(arkit_model, Track.load(einstein_take / "new.npz"), k)
    luma = result[k][:fan.shape[0], :fan.shape[1]] @ LUMA     # 817 wide, stored as 818
    assert fan.sum() > 200                     # the opening is wide: 432 of the face's pixels
    inside = np.median(luma[fan])
    assert inside < 0.6 * np.median(luma[lips])
    assert np.percentile(luma[fan], 95) > 2.0 * inside


SKIN, LIPS = (200, 160, 140), (170, 90, 90)


def _painted_mouth(model, jaw_open: float, inside_colour):
    """A 256² frame of the model's mean person with jawOpen ``jaw_open`` (facing the camera):
    skin everywhere, the lips in :data:`LIPS`, the mouth's opening (its fan, as a render of
    the whole face shows it) in ``inside_colour``; with its closed mesh, camera, topology,
    raster and fan mask."""
    from conftest import jaw_open_track
    from facetransfer.mouth import inside_mouth
    from facetransfer.render import rasterize
    from facetransfer.topology import close_mouth, mesh_topology

    track = jaw_open_track(model, [jaw_open])
    topo = mesh_topology(model)
    V = close_mouth(model.synthesize(track.weights_at(0)), topo)
    cam = track.camera(0)
    raster = rasterize(V, topo.faces, cam, (256, 256))
    fan = inside_mouth(raster.tri_id, topo)
    frame = np.empty((256, 256, 3), np.uint8)
    frame[:] = SKIN
    frame[np.isin(raster.tri_id, topo.mouth_faces) & ~fan] = LIPS
    frame[fan] = inside_colour
    return frame, V, cam, topo, raster, fan


def _width(model, V, cam):
    lm = np.asarray(model.landmarks)
    return float(np.linalg.norm(np.subtract(*cam.project(V[lm[[60, 64]]]))))


def test_what_a_frame_shows_of_the_inside_is_its_dark_opening(arkit_model):
    """:func:`shown_inside` of a frame whose open mouth is black counts the whole opening
    (its pixels over the squared inner mouth width, as the render draws it, within 2 %); of
    the same mouth showing the lips' colour (shut lips the track has open), none; the skin's
    and the lips' colours are read back."""
    from facetransfer.mouth_inside import shown_inside

    lm = np.asarray(arkit_model.landmarks)[[60, 64]]
    frame, V, cam, topo, _, fan = _painted_mouth(arkit_model, 0.7, (10, 5, 5))
    truth = fan.sum() / _width(arkit_model, V, cam) ** 2
    assert truth > 0.2
    seen = shown_inside(frame, V, cam, topo, lm)
    assert seen.shown == pytest.approx(truth, rel=0.02)
    assert np.array_equal(seen.skin, SKIN) and np.array_equal(seen.lips, LIPS)
    frame[fan] = LIPS
    assert shown_inside(frame, V, cam, topo, lm).shown == 0.0


def test_the_inside_is_drawn_only_where_the_frames_never_show_one(arkit_model):
    """:func:`paint_inside` on a wide-open mouth whose texture shows the lips' colour across
    the opening (a photo's shut lips stretched): where the target's frames show no inside,
    the upper teeth show under the upper lip, brighter than the lips, and a dark cavity under
    them (a fifth of the opening's middle under 0.6 of the lips' luminance: 0.41 measured);
    where they show an inside a quarter as large as this opening (a clip that talks), nothing
    changes, to the bit; nor at a mouth that hardly parts (jawOpen 0: an opening of 0.01)."""
    from facetransfer.mouth_inside import DrawnInside, paint_inside

    lm = np.asarray(arkit_model.landmarks)
    frame, V, cam, topo, raster, fan = _painted_mouth(arkit_model, 0.7, LIPS)
    opening = fan.sum() / _width(arkit_model, V, cam) ** 2

    def drawn(shown):
        return DrawnInside(shown, np.array([60.0, 22, 20]), np.array([102.0, 54, 54]),
                           np.array([190.0, 185, 170]), lm[[60, 64]], lm[[36, 39, 42, 45]])

    img = frame.copy()
    assert paint_inside(img, raster, V, cam, topo, drawn(opening / 4), fan) == 0.0
    assert np.array_equal(img, frame)
    assert paint_inside(img, raster, V, cam, topo, drawn(0.0), fan) == 1.0
    assert np.array_equal(img[~fan], frame[~fan])             # the opening only
    luma, lip = img[fan] @ LUMA, np.asarray(LIPS) @ LUMA
    ys, xs = np.nonzero(fan)
    middle = np.abs(xs - np.median(xs)) < 0.15 * np.ptp(xs)
    top = ys <= np.percentile(ys, 15)                          # under the upper lip
    assert np.median(luma[top & middle]) > lip                 # the upper teeth
    assert np.mean(luma[middle] < 0.6 * lip) > 0.2            # the cavity below them
    shut, V0, cam0, topo0, raster0, fan0 = _painted_mouth(arkit_model, 0.0, LIPS)
    img = shut.copy()
    assert paint_inside(img, raster0, V0, cam0, topo0, drawn(0.0), fan0) == 0.0
    assert np.array_equal(img, shut)


def test_a_target_with_cuts_measures_its_inside_over_the_whole_clip(quick_model, quick_track,
                                                                    monkeypatch):
    """A ready performance onto a target with a cut: each shot is rendered as a clip of its
    own, but the mouth's texture comes from the whole clip's frames (the mouth source's index
    counts them from the clip's first), so the inside those frames show is measured there.
    Before, each shot handed :func:`drawn_inside` its own frames and track with the whole
    clip's numbers: the second shot's rows past its length were dropped, the others read the
    wrong frames."""
    import dataclasses

    import facetransfer.rewrite_clip as rc
    from facetransfer.rewrite_clip import MouthSource, rewrite_frame_parts
    from facetransfer.track.project import take_frames

    n, cut = quick_track.n_frames, 20
    target = dataclasses.replace(quick_track, shot_starts=(cut,))
    frames = np.random.default_rng(0).integers(0, 255, (n, 64, 64, 3), dtype=np.uint8)
    index = np.arange(n)[::-1].copy()           # the nearest frames: any of the clip's
    seen = []

    def spy(frames_, track_, model_, topo_, rows):
        seen.append((len(frames_), track_.n_frames, np.unique(rows).tolist()))

    monkeypatch.setattr(rc, "drawn_inside", spy)
    mouth = MouthSource(frames, take_frames(target, index), index, own=True)
    list(rewrite_frame_parts(frames, target, target, quick_model, mouth_source=mouth,
                             options=rc.RewriteOptions(mouth="frame")))
    assert len(seen) == 2                                   # one renderer a shot
    assert all(s == (n, n, list(range(n))) for s in seen), seen


def _teeth_halves(model, yaw: float) -> tuple[int, int]:
    """``(near, far)``: the upper teeth's pixels (luminance over 130: the teeth facing the light
    are 185, the lips 114, the cavity 32) that :func:`paint_inside` draws into the mean person's
    opening (jawOpen 0.7, turned ``yaw`` degrees about the vertical), on the camera's side of
    the upper lip's middle and beyond it."""
    from scipy.spatial.transform import Rotation

    from conftest import jaw_open_track
    from facetransfer.mouth import inside_mouth
    from facetransfer.mouth_inside import DrawnInside, paint_inside
    from facetransfer.render import rasterize
    from facetransfer.topology import close_mouth, mesh_topology

    lm = np.asarray(model.landmarks)
    track = jaw_open_track(model, [0.7], rotation=Rotation.from_euler("y", yaw, degrees=True)
                           .as_matrix(), scale=30.0)
    topo = mesh_topology(model)
    V = close_mouth(model.synthesize(track.weights_at(0)), topo)
    cam = track.camera(0)
    c = cam.project(V[-1:])[0]
    cam = cam.shifted(c[0] - 128.0, c[1] - 128.0)              # the mouth in the middle
    raster = rasterize(V, topo.faces, cam, (256, 256))
    fan = inside_mouth(raster.tri_id, topo)
    img = np.empty((256, 256, 3), np.uint8)
    img[:] = LIPS
    inside = DrawnInside(0.0, np.array([60.0, 22, 20]), np.array([102.0, 54, 54]),
                         np.array([190.0, 185, 170]), lm[[60, 64]], lm[[36, 39, 42, 45]])
    assert paint_inside(img, raster, V, cam, topo, inside, fan) == 1.0
    loop = V[topo.mouth_loop]
    upper = loop[loop[:, 1] > loop[:, 1].mean()]
    middle = upper[np.argmin(np.abs(upper[:, 0] - 0.5 * (loop[:, 0].min() + loop[:, 0].max())))]
    x = cam.project(middle[None])[0, 0]
    ys, xs = np.nonzero(fan)
    teeth = img[ys, xs] @ LUMA > 130
    side = np.sign(cam.rotation[0, 2]) or 1.0     # the far side: where the head's +z turns to
    far = (xs - x) * side > 0
    return int(np.sum(teeth & ~far)), int(np.sum(teeth & far))


@pytest.mark.parametrize("yaw", [30.0, -30.0])
def test_a_turned_heads_teeth_follow_the_dental_arch(arkit_model, yaw):
    """On a head turned 30°, the teeth are drawn on the dental arch behind the lips seen along
    the camera's view: the far side's teeth, on the arch's side turned away, are foreshortened.
    Their pixels beyond the upper lip's middle are 0.55 and 0.61 of the near side's (the arch
    ``z = -0.81 x²`` at the teeth's half-width, 0.46 eye widths, projects to 0.65); the
    flat band painted on the opening's surface (a cone whose far half recedes out of view) drew
    0.15-0.18 there. Facing the camera, the two sides are alike (515 and 496 pixels)."""
    near, far = _teeth_halves(arkit_model, yaw)
    assert near > 400
    assert 0.4 < far / near < 0.85
    n0, f0 = _teeth_halves(arkit_model, 0.0)
    assert n0 > 400 and abs(n0 - f0) < 0.03 * (n0 + f0)


def test_the_drawn_teeth_are_as_bright_over_the_skin_as_real_teeth():
    """The drawn teeth's luminance over the skin's is the median of what real teeth show
    (:data:`facetransfer.mouth_inside.TEETH_LEVEL`: 1.55, 1.48, 1.35, 0.85, 0.67 measured):
    on a face darkened to takeo's 0.35 (skin 33) the teeth are 1.35 times its luminance, at
    least the 1.35 of the dimmest real source whose upper teeth show lit (``driving_d6``;
    before, 1.25: under all three); one gain, the palette's hue kept, and a bright skin's
    teeth clipped at white."""
    from facetransfer.mouth_inside import _colours
    from facetransfer.palette import PALETTE

    skin, lips = np.array([36.0, 32.0, 29.0]), np.array([40.0, 25.0, 25.0])
    teeth = _colours(skin, lips, lips * 0.5)[2]
    assert 1.34 < (teeth @ LUMA) / (skin @ LUMA) < 1.36
    palette = np.asarray(PALETTE["teeth"], np.float64)
    assert np.allclose(teeth / (teeth @ LUMA), palette / (palette @ LUMA))
    assert np.all(_colours(skin * 6.5, lips, lips)[2] <= 255.0)
