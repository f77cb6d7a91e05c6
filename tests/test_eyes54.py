"""The track's eye openings on the eyes (fifty-fourth session, helper eyes54): a photo read
twice by Face Landmarker (its second look in the region of its own points)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.io.video import read_video
from facetransfer.track.landmarks import MP_EYE_CONTOURS


def _to_chain(p: np.ndarray, chain: np.ndarray) -> float:
    """Distance of the point ``p`` (2,) from the polyline ``chain`` (m, 2)."""
    a, d = chain[:-1], np.diff(chain, axis=0)
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * d - p, axis=1).min())


def test_a_photo_is_read_again_and_its_near_eye_lies_on_the_eye(data_dir):
    """``stills/breakingbad.jpg`` (the head turned ~50 degrees, glasses): Face Landmarker's
    first look put the near (left) eye's contour on the lower lid's skin below the iris, its
    lids 9.3 px from the human points (the eye 72 px wide) and its corners 8.2 px; a transfer
    onto the photo showed that skin as the eyeball, turned to the new gaze as a salmon disc.
    The photo is now looked at twice, the second look in the region the first one's points
    give: its lids 2.0 px from the human points, its corners 3.8 px."""
    from facetransfer.track.capture import detect_video

    photo = data_dir / "stills" / "breakingbad.jpg"
    truth = np.loadtxt(photo.with_suffix(".pts"), skiprows=3, comments="}")
    det = detect_video(photo)[0]
    q = np.asarray(det.points478[0], float)
    ring = MP_EYE_CONTOURS[1]                          # the subject's left eye
    lower, upper = q[list(ring[:9])], q[list(ring[8:]) + [ring[0]]]
    lids = [_to_chain(truth[k], upper) for k in (43, 44)] + \
        [_to_chain(truth[k], lower) for k in (46, 47)]
    corners = [np.linalg.norm(q[ring[8]] - truth[42]), np.linalg.norm(q[ring[0]] - truth[45])]
    assert np.mean(lids) < 3.5, lids
    assert np.mean(corners) < 5.5, corners


def test_only_a_picture_is_looked_at_twice(data_dir):
    """A clip of one frame keeps Face Landmarker's second look at it; a clip of two frames
    its first look at its first frame, as before (video mode: the second look reads the frame
    in the region of its own first points, and differs)."""
    from facetransfer.track.capture import detect_video
    from facetransfer.track.detect import VideoLandmarker

    frames = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=2)[0]
    with VideoLandmarker(fps=25.0, blendshapes=True) as lm:  # an array's clock: 25 fps
        first, again = lm.detect478(frames[0]), lm.detect478(frames[0])
    assert not np.array_equal(first, again)
    one = detect_video(frames[:1])[0].points478[0]
    two = detect_video(frames)[0].points478[0]
    assert np.array_equal(one, again.astype(one.dtype))
    assert np.array_equal(two, first.astype(two.dtype))


@pytest.mark.parametrize("suffix", [".png", ".tif", ".bmp", ".webp"])
def test_a_photo_of_any_format_is_a_clip_of_one_frame(data_dir, tmp_path, suffix):
    """A still image is read as a clip of one frame whatever its format. OpenCV counts a
    JPEG's frames 1 but a PNG's, TIFF's, BMP's or WebP's 0, and ``video_info`` said 0: such a
    photo was looked at once by Face Landmarker (the second look is keyed to a clip of one
    frame) and ``transfer --target photo.png --out r.png --frame 0`` was refused."""
    from facetransfer.io.video import video_info

    photo = tmp_path / f"takeo{suffix}"
    assert cv2.imwrite(str(photo), cv2.imread(str(data_dir / "stills" / "takeo.ppm")))
    assert video_info(photo).n_frames == 1


def test_a_png_photo_is_looked_at_twice_as_a_jpeg_is(data_dir, tmp_path):
    """``track photo.png`` (the file) detects as a transfer onto it does (its one decoded
    frame): Face Landmarker's second look. Before, the file's count of 0 frames gave the PNG
    one look, so ``track``, ``batch track`` and a transfer's target track of one PNG differed
    (breakingbad's near eye back on the lower lid, 15 px from the second look)."""
    from facetransfer.track.capture import detect_video

    photo = tmp_path / "breakingbad.png"
    assert cv2.imwrite(str(photo), cv2.imread(str(data_dir / "stills" / "breakingbad.jpg")))
    frames = read_video(photo)[0]
    assert len(frames) == 1
    from_file = detect_video(photo)[0].points478[0]
    from_frames = detect_video(frames)[0].points478[0]
    np.testing.assert_array_equal(from_file, from_frames)


def test_a_png_photo_has_its_one_frame_to_write(data_dir, tmp_path, capsys):
    """``--frame N`` of a PNG photo's rewrite is checked against its one frame (0): before,
    ``--frame 0`` was refused as ``the transfer has 0 frames``."""
    from facetransfer.cli.main import main

    photo = tmp_path / "takeo.png"
    assert cv2.imwrite(str(photo), cv2.imread(str(data_dir / "stills" / "takeo.ppm")))
    code = main(["transfer", "--target", str(photo), "--identity-label", "any",
                 "--out", str(tmp_path / "r.png"), "--frame", "1"])
    err = capsys.readouterr().err
    assert code == 2
    assert f"--frame 1: the transfer has 1 frame (the target {photo}'s), 0" in err, err
    assert not (tmp_path / "r.png").exists()
