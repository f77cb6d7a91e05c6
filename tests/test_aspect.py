"""Videos of non-square pixels tracked at the face's shown shape (facetransfer.track.aspect)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from facetransfer.errors import TrackError
from facetransfer.render import WeakPerspective, rotation_from_euler
from facetransfer.track.aspect import (View, aspect_of, display_frames,
                                       shown_width, stored_pixels, to_shown_x, to_stored_x)
from facetransfer.track.result import Track


def test_the_shown_width_rounds_and_the_aspect_is_what_the_resampling_does():
    assert shown_width(1440, (4, 3)) == 1920 and aspect_of(1440, (4, 3)) == 4 / 3
    assert shown_width(512, (15, 16)) == 480 and aspect_of(512, (15, 16)) == 480 / 512
    assert shown_width(720, (10, 11)) == 655 and aspect_of(720, (10, 11)) == 655 / 720
    assert aspect_of(8, (1001, 1000)) == 1.0          # the rounding leaves the width: square
    assert aspect_of(640, (1, 1)) == 1.0


@pytest.mark.parametrize("aspect", [4 / 3, 0.8, 480 / 512])
def test_columns_map_as_opencv_resamples(aspect):
    """Shown frames resampled to the stored width by OpenCV: a ramp holding each shown column's
    own ``x`` comes back at stored column ``j`` (inside the border) as ``to_shown_x(j)``."""
    W = 300
    w = int(round(W * aspect))
    ramp = np.tile(np.arange(w, dtype=np.float64), (4, 1))
    stored = cv2.resize(ramp, (W, 4), interpolation=cv2.INTER_LINEAR)[0]
    j = np.arange(2, W - 2)
    np.testing.assert_allclose(stored[j], to_shown_x(j, w / W), atol=1e-9)
    np.testing.assert_allclose(to_stored_x(to_shown_x(j, aspect), aspect), j, atol=1e-12)


def test_display_frames_resample_columns_and_pass_placeholders():
    fr = np.random.default_rng(0).integers(0, 256, (6, 10, 3), np.uint8)
    out = list(display_frames([fr, None, fr], 0.8))
    assert out[1] is None and out[0].shape == (6, 8, 3)
    np.testing.assert_array_equal(out[0], cv2.resize(fr, (8, 6), interpolation=cv2.INTER_LINEAR))
    half = list(display_frames([fr], 0.5))[0]          # narrower than LINEAR_SHRINK: averaged
    np.testing.assert_array_equal(half, cv2.resize(fr, (5, 6), interpolation=cv2.INTER_AREA))
    assert not np.array_equal(half, cv2.resize(fr, (5, 6), interpolation=cv2.INTER_LINEAR))
    frames = [fr]
    assert list(display_frames(frames, 1.0))[0] is fr


def test_the_cameras_pixel_aspect_divides_the_columns():
    R = rotation_from_euler(0.3, -0.2, 0.1)
    X = np.random.default_rng(1).normal(size=(20, 3))
    shown = WeakPerspective(9.0, R, np.array([200.0, 150.0]))
    a = 0.8
    stored = WeakPerspective(9.0, R, np.array([to_stored_x(200.0, a), 150.0]), a)
    p, q = shown.project(X), stored.project(X)
    np.testing.assert_allclose(q[:, 0], to_stored_x(p[:, 0], a), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(q[:, 1], p[:, 1])
    assert stored.shifted(5, 7).pixel_aspect == a
    with pytest.raises(ValueError, match="pixel aspect"):
        WeakPerspective(9.0, R, np.zeros(2), 0.0)


def _track(n=5, aspect=1.0):
    rng = np.random.default_rng(2)
    R = np.stack([rotation_from_euler(*rng.uniform(-0.3, 0.3, 3)) for _ in range(n)])
    return Track(fps=30.0, frame_size=(384, 480), rotation=R, scale=rng.uniform(8, 12, n),
                 translation=rng.uniform(150, 300, (n, 2)),
                 weights={"identity": np.zeros((n, 3)), "expression": rng.normal(size=(n, 4))},
                 landmarks2d=rng.uniform(100, 300, (n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash="", mode_names=("identity", "expression"),
                 detections2d=rng.uniform(100, 300, (n, 68, 2)), pixel_aspect=aspect)


def test_a_shown_track_told_in_stored_pixels_projects_onto_the_stored_frame():
    a = 1.25
    shown = _track()
    stored = stored_pixels(shown, a)
    assert stored.pixel_aspect == a and stored.frame_size == shown.frame_size
    X = np.random.default_rng(3).normal(size=(10, 3))
    for i in range(shown.n_frames):
        p, q = shown.camera(i).project(X), stored.camera(i).project(X)
        np.testing.assert_allclose(q[:, 0], to_stored_x(p[:, 0], a), atol=1e-9)
        np.testing.assert_allclose(q[:, 1], p[:, 1], atol=1e-12)
    for name in ("landmarks2d", "detections2d"):
        np.testing.assert_allclose(getattr(stored, name)[..., 0],
                                   to_stored_x(getattr(shown, name)[..., 0], a))
    assert stored_pixels(shown, 1.0) is shown


def test_project_landmarks_and_the_head_translation_use_the_aspect(arkit_model):
    from facetransfer.export.common import head_translation
    from facetransfer.track.project import project_landmarks
    from conftest import synthetic_arkit_track

    shown = synthetic_arkit_track(arkit_model, 4)[0]                  # 640x480
    stored = dataclasses.replace(stored_pixels(shown, 1.25), frame_size=(512, 480))
    a, b = project_landmarks(shown, arkit_model), project_landmarks(stored, arkit_model)
    np.testing.assert_allclose(b.landmarks2d[..., 0], to_stored_x(a.landmarks2d[..., 0], 1.25),
                               atol=1e-9)
    # the head's place from the frame's centre as shown: the shown track's (640 = 512 x 1.25)
    np.testing.assert_allclose(head_translation(stored), head_translation(shown), atol=1e-9)


def test_the_track_file_keeps_the_pixel_aspect(tmp_path):
    tr = _track(aspect=0.9375)
    back = Track.load(tr.save(tmp_path / "t.npz"))
    assert back.pixel_aspect == 0.9375
    assert back.camera(0).pixel_aspect == 0.9375
    data = dict(np.load(tmp_path / "t.npz"))
    del data["pixel_aspect"]                           # a file of an older version: square
    np.savez(tmp_path / "old.npz", **data)
    assert Track.load(tmp_path / "old.npz").pixel_aspect == 1.0
    with pytest.raises(TrackError, match="pixel_aspect"):
        dataclasses.replace(tr, pixel_aspect=float("nan"))


def _two_shapes(data_dir, tmp_path, n):
    """``driving_d6``'s first ``n`` frames stored square (480x480) and squeezed to 384 columns
    with a sample aspect ratio of 5:4 (shown 480x480 again), both lossless."""
    from facetransfer.io.video import VideoOptions, read_video, write_video

    frames = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=n)[0]
    square, squeezed = tmp_path / "square.mkv", tmp_path / "squeezed.mkv"
    write_video(square, frames, 30.0, options=VideoOptions(crf=0))
    narrow = np.stack([cv2.resize(f, (384, 480), interpolation=cv2.INTER_AREA) for f in frames])
    write_video(squeezed, narrow, 30.0, options=VideoOptions(crf=0, sar=(5, 4)))
    return square, squeezed


def test_a_squeezed_clip_is_captured_as_the_square_one(arkit_model, data_dir, tmp_path):
    """A real clip stored at 4/5 of its width (HDV and DV store video so) is captured as the
    same clip in square pixels: the same activations, identity and head scale, and points that
    map onto the stored frames; fitted in the stored pixels instead (the aspect ignored), the
    activations differ several times as much."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.capture import capture_video

    square, squeezed = _two_shapes(data_dir, tmp_path, 60)
    ref = capture_video(square, arkit_model)
    tr = capture_video(squeezed, arkit_model)
    flat = capture_video(squeezed, arkit_model, view=View())
    assert tr.pixel_aspect == 1.25 and tr.frame_size == (384, 480) and flat.pixel_aspect == 1.0
    mouth = [ARKIT_NAMES.index(n) for n in ("jawOpen", "mouthSmileLeft", "mouthSmileRight",
                                            "mouthPucker", "mouthFunnel")]
    err = np.abs(tr.blendshapes[:, mouth] - ref.blendshapes[:, mouth]).mean()
    err_flat = np.abs(flat.blendshapes[:, mouth] - ref.blendshapes[:, mouth]).mean()
    assert err < 0.02 and err_flat > 3 * err
    np.testing.assert_allclose(tr.weights["identity"][0], ref.weights["identity"][0], atol=0.02)
    assert np.median(tr.scale / ref.scale) == pytest.approx(1.0, abs=0.01)
    d = tr.landmarks2d - np.stack([to_stored_x(ref.landmarks2d[..., 0], 1.25),
                                   ref.landmarks2d[..., 1]], axis=-1)
    assert np.median(np.abs(d)) < 0.3
    # the same squeezed frames as a DPX plate whose header says the pixels' 5:4 (an
    # anamorphic scan's): captured as the video that says it
    plate = _squeezed_plate(squeezed, tmp_path / "plate", 1.25)
    on_plate = capture_video(plate, arkit_model)
    assert on_plate.pixel_aspect == 1.25 and on_plate.frame_size == (384, 480)
    np.testing.assert_allclose(on_plate.blendshapes, tr.blendshapes, atol=1e-6)


def _squeezed_plate(video: Path, folder: Path, aspect: float) -> Path:
    """``video``'s frames as 10-bit DPX files of ITU-R 709 codes (read back as the same
    levels), the header's pixel aspect ratio ``aspect`` (OpenImageIO's attribute) and rate
    the video's 30 fps."""
    import OpenImageIO as oiio

    from facetransfer.io.dpx import DpxImage, write_dpx
    from facetransfer.io.video import read_video

    folder.mkdir()
    frames = read_video(video)[0]
    for i, rgb in enumerate(frames):
        spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, "uint16")
        spec.attribute("dpx:Transfer", "ITU-R 709-4")
        spec.attribute("PixelAspectRatio", aspect)
        spec.attribute("dpx:FrameRate", 30.0)                          # the video's
        codes = ((rgb.astype(np.uint32) * 1023 * 2 + 255) // 510).astype(np.uint16)
        write_dpx(folder / f"p.{i:04d}.dpx", DpxImage(codes, 10, "ITU-R 709-4", spec))
    assert np.array_equal(read_video(folder / "p.%04d.dpx")[0], frames)
    return folder / "p.%04d.dpx"


def test_the_fidelity_judge_sees_a_squeezed_clip_at_its_shape(data_dir, tmp_path):
    """Face Landmarker's scores (the demo's judge) on the squeezed frames told their aspect are
    its scores on the square ones, up to the resampling; not told, they differ far more."""
    from facetransfer.fidelity import landmarker_scores
    from facetransfer.io.video import read_video

    square, squeezed = (read_video(p)[0] for p in _two_shapes(data_dir, tmp_path, 40))
    ref = landmarker_scores(square, 30.0)[0]
    shown = landmarker_scores(squeezed, 30.0, 1.25)[0]
    stored = landmarker_scores(squeezed, 30.0)[0]
    err, err_stored = np.nanmean(np.abs(shown - ref)), np.nanmean(np.abs(stored - ref))
    assert err < 0.01 and err_stored > 3 * err


def _turned(clip, out):
    """``clip`` stored turned a quarter clockwise (lossless), with a display matrix that turns
    it back upright for players (a phone held upright stores its video so)."""
    import subprocess

    import imageio_ffmpeg

    from facetransfer.io.video import VideoOptions, read_video, write_video
    from facetransfer.io.video_read import video_info

    frames, fps = read_video(clip)
    n, d = video_info(clip).sar
    stored = out.with_name("stored.mkv")
    write_video(stored, np.stack([np.rot90(f, k=-1) for f in frames]), fps,
                options=VideoOptions(crf=0, sar=(d, n)))
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-display_rotation", "90",
                    "-i", str(stored), "-c", "copy", str(out)], check=True)
    return frames


def test_a_turned_clip_is_read_upright_with_its_pixels_turned_too(arkit_model, data_dir,
                                                                  tmp_path):
    """A clip whose display matrix turns it a quarter (stored 480x384 in pixels 4:5) is read
    and captured as it is shown: upright, 384x480 in pixels 5:4, the same capture as the
    upright clip; ``probe`` says so. Before, its pixels' ratio was taken unturned: the face
    tracked 1.56 times too wide."""
    from facetransfer.io.video import read_video
    from facetransfer.io.video_facts import fact_lines, video_facts
    from facetransfer.io.video_read import video_info
    from facetransfer.track.capture import capture_video

    squeezed = _two_shapes(data_dir, tmp_path, 30)[1]
    upright = _turned(squeezed, tmp_path / "turned.mp4")
    info = video_info(tmp_path / "turned.mp4")
    assert (info.turn, info.size, info.sar) == (270, (384, 480), (5, 4))
    got = read_video(tmp_path / "turned.mp4")[0]
    assert got.shape == upright.shape
    err = np.abs(got.astype(int) - upright).mean()      # chroma resampled once more
    assert err < 2.0 and np.abs(got.astype(int) - upright[:, ::-1, ::-1]).mean() > 10 * err
    line = fact_lines(video_facts(tmp_path / "turned.mp4"))[0]
    assert "stored 480x384, turned 270 degrees clockwise" in line and "shown 480x480" in line
    ref, tr = capture_video(squeezed, arkit_model), capture_video(tmp_path / "turned.mp4",
                                                                   arkit_model)
    assert tr.pixel_aspect == 1.25 and tr.frame_size == (384, 480)
    assert np.abs(tr.blendshapes - ref.blendshapes).mean() < 0.01
    np.testing.assert_allclose(tr.weights["identity"][0], ref.weights["identity"][0], atol=0.02)
