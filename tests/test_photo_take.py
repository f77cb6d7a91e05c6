"""A photo as a transfer's target performs a whole Live Link Face take (``transfer --target
portrait.jpg --expression-from take.csv``): the take's frames as ``view`` and ``puppet`` of it
number them, at its rows' rate, the photo's head held, no audio. Before, one frame."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.arkit import ARKIT_NAMES, MEDIAPIPE_NAMES  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.export.livelink import read_livelink, write_livelink  # noqa: E402
from facetransfer.io.video import read_video  # noqa: E402
from facetransfer.take import take_length, take_track  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.project import take_frames  # noqa: E402
from facetransfer.transfer_plan import plan_transfer  # noqa: E402
import test_take  # noqa: E402

arkit_clip = test_take.arkit_clip     # a 10-frame clip of the ARKit model's person, shared
JAW = ARKIT_NAMES.index("jawOpen")


def run(argv, capsys):
    code = main([str(a) for a in argv])
    said = capsys.readouterr()
    return code, said.out, said.err


@pytest.fixture(scope="module")
def photo(arkit_clip):
    """The ARKit clip's first frame as ``photo.png`` with its truth track of one frame."""
    frames, _ = read_video(arkit_clip / "target.mp4", max_frames=1)
    cv2.imwrite(str(arkit_clip / "photo.png"), cv2.cvtColor(frames[0], cv2.COLOR_RGB2BGR))
    tt = Track.load(arkit_clip / "target.npz")
    dataclasses.replace(take_frames(tt, np.array([0])),
                        source=str(arkit_clip / "photo.png")).save(arkit_clip / "photo.npz")
    return arkit_clip / "photo.png", arkit_clip / "photo.npz", frames[0]


def _take(model, make_arkit_track, folder: Path, name: str, n: int, fps: float,
          drop: int | None = None) -> Path:
    """A take of ``n`` rows at ``fps`` written by the exporter; ``drop``: that row left out
    (a take with a dropped row, as the app writes one under load)."""
    take = write_livelink(make_arkit_track(model, n, fps=fps, seed=n)[0], folder / name)
    if drop is not None:
        lines = take.read_text().splitlines(keepends=True)
        take.write_text("".join(lines[:drop + 1] + lines[drop + 2:]))
    return take


@pytest.mark.parametrize("n, fps, drop", [(30, 30.0, None), (30, 30.0, 12), (70, 60.0, None),
                                          (1, 30.0, None)])
def test_a_photo_performs_the_take_on_the_frames_view_numbers(photo, arkit_model,
                                                              make_arkit_track, tmp_path,
                                                              n, fps, drop):
    """The plan of a photo performing a take: as many frames, at the rate, and with the
    activations of :func:`take_track` (what ``puppet`` renders and ``view`` shows; a dropped
    row's frame between its neighbours), the photo held in every frame with its head's pose.
    Before: one frame (the take's first row), at the photo's 25 fps."""
    take = _take(arkit_model, make_arkit_track, tmp_path, "take.csv", n, fps, drop)
    still, still_track, frame = photo
    plan = plan_transfer(still, arkit_model, target_track=still_track, expression_from=take)
    shown = take_track(take, arkit_model, arkit_model.training_weights("identity",
                                                                       arkit_model.labels[0][2]))
    # a take of one row shows no rate: the smallest timecode rate above its frame number, 24
    rate = fps if n > 1 else 24.0
    assert (plan.n_frames, plan.fps) == (shown.n_frames, shown.fps) == (n, rate)
    assert take_length(take) == (n, rate)
    np.testing.assert_allclose(plan.new_track.blendshapes, shown.blendshapes, atol=1e-5)
    a = read_livelink(take).activations
    if drop is not None:   # the dropped row's frame halfway between the rows beside it
        np.testing.assert_allclose(plan.new_track.blendshapes[drop],
                                   np.clip((a[drop - 1] + a[drop]) / 2, 0, 1), atol=1e-5)
    assert len(plan.target_frames) == n and np.array_equal(plan.target_frames[-1], frame)
    held = Track.load(still_track)
    np.testing.assert_array_equal(plan.new_track.rotation, np.repeat(held.rotation, n, 0))
    np.testing.assert_array_equal(plan.new_track.translation,
                                  np.repeat(held.translation, n, 0))


def test_a_photo_performing_a_take_written_whole_or_one_row(photo, arkit_model_path,
                                                            arkit_model, make_arkit_track,
                                                            tmp_path, capsys):
    """On the command line: a video of the take's rows at their rate, said without audio
    (``--max-frames 4``: its first four); ``--out x.png --frame 7`` row 7's expression (its
    saved track's activations are the row's), ``--frame 36`` of 36 rows refused in one
    line; a take whose timecodes repeat refused in one line, nothing written."""
    take = _take(arkit_model, make_arkit_track, tmp_path, "take.csv", 36, 30.0)  # > 1 s
    still, still_track, frame = photo
    base = ["transfer", "--target", still, "--target-track", still_track, "--model",
            arkit_model_path, "--no-progress", "--expression-from", take, "--out"]
    code, said, err = run(base + [tmp_path / "whole.mp4"], capsys)
    assert code == 0, err
    frames, fps = read_video(tmp_path / "whole.mp4")
    assert (len(frames), fps) == (36, 30.0)
    assert "36 frames, no audio (a take has none)" in said
    four = plan_transfer(still, arkit_model, target_track=still_track, expression_from=take,
                         max_frames=4)     # --max-frames 4
    assert (four.n_frames, len(four.target_frames), four.fps) == (4, 4, 30.0)
    code, said, err = run(base + [tmp_path / "one.png", "--frame", 7, "--save-track",
                                  tmp_path / "one.npz"], capsys)
    assert code == 0 and "frame 7" in said, err
    row = read_livelink(take).activations[7]
    np.testing.assert_allclose(Track.load(tmp_path / "one.npz").blendshapes[0], row, atol=1e-5)
    assert cv2.imread(str(tmp_path / "one.png")).shape == frame.shape
    code, _, err = run(base + [tmp_path / "two.png", "--frame", 36], capsys)
    assert code == 2 and "0-35" in err and len(err.strip().splitlines()) == 1, err
    lines = take.read_text().splitlines()
    (tmp_path / "rep.csv").write_text("\n".join(lines[:3] + lines[2:]) + "\n")
    for out in ("rep.mp4", "rep.png"):
        code, _, err = run(base[:-3] + ["--expression-from", tmp_path / "rep.csv", "--out",
                                        tmp_path / out], capsys)
        assert code == 2 and "repeat at row 3" in err and len(err.strip().splitlines()) == 1
        assert "Traceback" not in err and not (tmp_path / out).exists()


def test_a_photo_performs_a_take_of_a_real_clip(data_dir, arkit_model_path, tmp_path, capsys):
    """A take exported from the track of 30 frames of ``driving_d6`` (the jaw shut, then
    opening and closing as the speaker starts to talk, as a phone's take records it) onto the
    photo ``stills/takeo.ppm``: a video of 30 frames at 30 fps in which Face Landmarker's
    jawOpen follows the take's JawOpen curve. Before: one frame, the take's first row."""
    from facetransfer.fidelity import landmarker_scores
    from facetransfer.io.video import write_video

    frames, _ = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=72)
    write_video(tmp_path / "d6.mp4", frames[42:], 30.0)
    for argv in (["track", tmp_path / "d6.mp4", "--out", tmp_path / "d6.npz"],
                 ["export", tmp_path / "d6.npz", "--out", tmp_path / "take.csv"],
                 ["transfer", "--target", data_dir / "stills" / "takeo.ppm", "--expression-from",
                  tmp_path / "take.csv", "--out", tmp_path / "takeo.mp4"]):
        code, said, err = run(argv + ["--model", arkit_model_path, "--no-progress"], capsys)
        assert code == 0, err
    assert "30 frames" in said
    result, fps = read_video(tmp_path / "takeo.mp4")
    assert (len(result), fps) == (30, 30.0)
    curve = read_livelink(tmp_path / "take.csv").activations[:, JAW]
    assert np.ptp(curve) > 0.4                  # the take opens the jaw
    jaw = landmarker_scores(result, fps)[0][:, MEDIAPIPE_NAMES.index("jawOpen")]
    assert np.isfinite(jaw).all() and np.corrcoef(jaw, curve)[0, 1] > 0.8


def test_a_photos_mouth_texture_is_lifted_once(photo, arkit_model, make_arkit_track, tmp_path):
    """The mouth's texture function of a photo performing a take is lifted from the photo
    once, and gives the texture the 30 copies of it gave (each the photo): before, every held
    copy was lifted (up to 120; 27 of a 240-row take's 44 s on ``einstein.jpg``)."""
    from facetransfer.texture.face import mouth_texture_function
    from facetransfer.texture.function import attribute_vector

    take = _take(arkit_model, make_arkit_track, tmp_path, "take.csv", 30, 30.0)
    still, still_track, _ = photo
    plan = plan_transfer(still, arkit_model, target_track=still_track, expression_from=take)
    once = plan.mouth_function(arkit_model, tex_size=64)
    every = mouth_texture_function(arkit_model, plan.target_frames, plan.target_track,
                                   tex_size=64)
    assert once.frames.tolist() == [0] and len(every.frames) == 30
    for i in (0, 17):
        a = attribute_vector(arkit_model, {m: w[i] for m, w in plan.new_track.weights.items()})
        assert np.array_equal(once.texture(a), every.texture(a))
