"""A photo as a transfer's target performs its expression source (a video of the source's
length and rate), and a transfer writes one image (``--out result.png``, ``--frame N``)."""

from __future__ import annotations

import dataclasses
import sys

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))

from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.video import read_video, write_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.project import take_frames  # noqa: E402
import test_transfer_cli  # noqa: E402

clips = test_transfer_cli.clips       # the synthetic clips' fixture, shared


def run(argv, capsys):
    code = main([str(a) for a in argv])
    said = capsys.readouterr()
    return code, said.out, said.err


@pytest.fixture(scope="module")
def photo(clips, tmp_path_factory):
    """The target clip's first frame as ``photo.png`` with its track of one frame, and the
    source clip at 30 fps (the photo's own rate, 25, is not the output's)."""
    d = tmp_path_factory.mktemp("photo")
    frames, _ = read_video(clips["target"])
    cv2.imwrite(str(d / "photo.png"), cv2.cvtColor(frames[0], cv2.COLOR_RGB2BGR))
    tt = Track.load(clips["target_track"])
    dataclasses.replace(take_frames(tt, np.array([0])), source=str(d / "photo.png")).save(
        d / "photo.npz")
    sfr, _ = read_video(clips["source"])
    write_video(d / "source30.mp4", sfr, 30.0)
    st = Track.load(clips["source_track"])
    dataclasses.replace(st, fps=30.0, source=str(d / "source30.mp4")).save(d / "source30.npz")
    return {"photo": d / "photo.png", "photo_track": d / "photo.npz", "frame": frames[0],
            "source": d / "source30.mp4", "source_track": d / "source30.npz",
            "n_source": len(sfr)}


def _args(photo, quick_model_path, out):
    return ["transfer", "--target", photo["photo"], "--target-track", photo["photo_track"],
            "--expression-from", photo["source"], "--source-track", photo["source_track"],
            "--model", quick_model_path, "--out", out, "--no-progress"]


def test_a_photo_target_performs_the_whole_source(photo, quick_model_path, tmp_path, capsys):
    """Before, the photo's rewrite was one frame (the source's first expression)."""
    out = tmp_path / "animated.mp4"
    code, said, err = run(_args(photo, quick_model_path, out), capsys)
    assert code == 0, err
    frames, fps = read_video(out)
    assert len(frames) == photo["n_source"] and fps == 30.0
    assert f"{photo['n_source']} frames" in said
    diff = np.abs(frames.astype(int) - photo["frame"].astype(int)).max(axis=-1)
    assert diff[:, :10, :10].max() <= 12 and diff[:, :10, :10].mean() < 3  # the photo's, H.264
    assert diff[1, 40:100, 40:90].max() > 40      # frame 1's open mouth moved the photo's face
    # the photo's head held: every frame's corners and the face's place the photo's
    assert np.abs(frames[3].astype(int) - frames[5].astype(int))[:, :20].mean() < 3


def test_a_photo_rewrite_written_as_one_image(photo, quick_model_path, tmp_path, capsys):
    """``--out result.png`` was refused ("put a frame number in the name")."""
    seq = tmp_path / "seq_%05d.png"
    code, _, err = run(_args(photo, quick_model_path, seq), capsys)
    assert code == 0, err
    one = tmp_path / "result.png"
    code, said, err = run(_args(photo, quick_model_path, one), capsys)
    assert code == 0, err
    assert "one image, frame 0" in said
    # planned over the frames up to it alone: the lips' and mouth's few levels apart
    first = cv2.imread(str(tmp_path / "seq_00000.png")).astype(int)
    assert np.abs(cv2.imread(str(one)).astype(int) - first).max() <= 4
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("result")) == \
        ["result.png"]                           # nothing else left beside it
    code, said, err = run(_args(photo, quick_model_path, one) + ["--frame", 1], capsys)
    assert code == 2 and "exists" in err and len(err.strip().splitlines()) == 1
    code, said, err = run(_args(photo, quick_model_path, one) + ["--frame", 1, "--overwrite"],
                          capsys)
    assert code == 0, err
    second = cv2.imread(str(tmp_path / "seq_00001.png")).astype(int)
    assert np.abs(cv2.imread(str(one)).astype(int) - second).max() <= 4
    assert np.abs(second - first).max() > 40        # frame 1 is another expression


@pytest.mark.parametrize("out, extra, said", [
    ("x.png", [], "--frame N (0-5)"),             # a clip of six frames to one image
    ("x.mp4", ["--frame", "2"], "--max-frames"),  # --frame picks one image's frame
    ("x.png", ["--frame", "6"], "0-5"),           # beyond the transfer
])
def test_a_clip_to_one_image_is_refused_in_one_line(clips, quick_model_path, tmp_path,
                                                    capsys, out, extra, said):
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--expression-from", clips["source"],
                        "--source-track", clips["source_track"], "--model", quick_model_path,
                        "--out", tmp_path / out, "--no-progress", *extra], capsys)
    assert code == 2 and said in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and not list(tmp_path.iterdir())


def test_one_frame_of_a_clip_as_one_image(clips, quick_model_path, tmp_path, capsys):
    """``--frame 1`` of a video target: that frame of its rewrite as a sequence has it."""
    base = ["transfer", "--target", clips["target"], "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", quick_model_path, "--no-progress", "--out"]
    code, _, err = run(base + [tmp_path / "f_%05d.png"], capsys)
    assert code == 0, err
    code, _, err = run(base + [tmp_path / "one.png", "--frame", "1"], capsys)
    assert code == 0, err
    a = cv2.imread(str(tmp_path / "one.png")).astype(int)
    b = cv2.imread(str(tmp_path / "f_00001.png")).astype(int)
    assert np.abs(a - b).max() <= 4


@pytest.mark.parametrize("kind", ["alpha", "16-bit"])
def test_a_photo_with_alpha_or_16_bits_held_in_a_png_sequence(photo, quick_model_path,
                                                              tmp_path, capsys, kind):
    """An RGBA or a 16-bit PNG photo as the target of a PNG sequence: every frame keeps the
    photo's alpha or 16 bits. Before, the photo's alpha and 16-bit colour were decoded as a
    video's, one frame each: the transfer failed at frame 1 after all its tracking (``the
    alpha of still.png ends at frame 1``, exit 2), nothing written."""
    rgb = photo["frame"]
    h, w = rgb.shape[:2]
    if kind == "alpha":
        alpha = np.full((h, w), 255, np.uint8)
        alpha[:, : w // 4] = 90
        stored = np.dstack([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), alpha])
    else:
        stored = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257 + 3
    still = tmp_path / "still.png"
    cv2.imwrite(str(still), stored)
    track = tmp_path / "still.npz"
    dataclasses.replace(Track.load(photo["photo_track"]), source=str(still)).save(track)
    args = _args(photo, quick_model_path, tmp_path / "a_%05d.png")
    args[2], args[4] = still, track
    code, said, err = run(args, capsys)
    assert code == 0, err
    assert ("with the target's alpha" if kind == "alpha" else "16 bits") in said
    written = [cv2.imread(str(tmp_path / f"a_{i:05d}.png"), cv2.IMREAD_UNCHANGED)
               for i in range(photo["n_source"])]
    for out in written:
        if kind == "alpha":
            assert out.shape == (h, w, 4) and np.array_equal(out[..., 3], alpha)
        else:   # the photo's 16-bit values where the face is not
            assert out.dtype == np.uint16 and np.array_equal(out[:10, :10], stored[:10, :10])


def test_a_photo_target_performs_a_ready_performance(photo, quick_model_path, tmp_path,
                                                     capsys):
    """``--performance NEW.npz`` (a photo's transfer saved with ``--save-track``, edited)
    onto the photo: a video of the performance's frames at its rate, as an expression source
    gives. Before, one frame (the performance's first, the rest dropped without a word), and
    ``--frame 2 --out one.png`` was refused (``the transfer has 1 frames``)."""
    base = ["transfer", "--target", photo["photo"], "--target-track", photo["photo_track"],
            "--performance", photo["source_track"], "--model", quick_model_path,
            "--no-progress", "--out"]
    code, said, err = run(base + [tmp_path / "performed.mp4"], capsys)
    assert code == 0, err
    frames, fps = read_video(tmp_path / "performed.mp4")
    assert len(frames) == photo["n_source"] and fps == 30.0
    assert f"{photo['n_source']} frames" in said
    assert np.abs(frames[1].astype(int) - frames[0].astype(int)).max() > 40  # it moves
    code, said, err = run(base + [tmp_path / "one.png", "--frame", "2"], capsys)
    assert code == 0, err
    assert "frame 2" in said
    code, _, err = run(base + [tmp_path / "two.png", "--frame", str(photo["n_source"])], capsys)
    assert code == 2 and f"0-{photo['n_source'] - 1}" in err, err


def test_an_exif_turned_jpeg_photo_is_read_upright(tmp_path):
    """A phone's portrait photo is stored sideways with EXIF orientation 6; read as a clip of
    one frame (a transfer's target, ``track``, ``puppet``) it is upright, as every viewer shows
    it. Before, OpenCV's capture gave it sideways (60x40 for a 40x60 portrait): the face
    tracked lying down, the output a sideways video."""
    from PIL import Image

    from facetransfer.io.video import video_info

    upright = np.zeros((60, 40, 3), np.uint8)
    upright[:20] = (250, 40, 40)                 # the top third red: which way is up
    exif = Image.Exif()
    exif[0x0112] = 6                             # shown turned a quarter clockwise
    stored = Image.fromarray(upright).transpose(Image.Transpose.ROTATE_90)
    stored.save(tmp_path / "portrait.jpg", exif=exif, quality=95)
    assert stored.size == (60, 40)
    frames, _ = read_video(tmp_path / "portrait.jpg")
    assert frames.shape == (1, 60, 40, 3)
    assert video_info(tmp_path / "portrait.jpg").size == (40, 60)
    assert np.abs(frames[0].astype(int) - upright.astype(int)).mean() < 6
    from facetransfer.io.video import iter_frames   # the frame readers of track and texture

    assert np.array_equal(next(iter_frames(tmp_path / "portrait.jpg")), frames[0])
