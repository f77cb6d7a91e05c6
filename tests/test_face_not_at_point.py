"""``--face X,Y`` (``track``, ``puppet``, ``batch track``; ``transfer --target-face`` /
``--source-face``) on a point where no face lies: before, the face nearest it (or the only one)
was followed in silence; now one line names the point, the file and the faces found, exit 2
(facetransfer.track.face_crop.FaceNotAtPoint; BENCHMARKS.md, "Fifty-fourth session (helper
fix54)"). ``stills/breakingbad.jpg``: two people, faces centred near (1428, 295) and
(758, 335) of its 1920x1080 pixels; (960, 100) is the wall between and above them."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.errors import TrackError
from facetransfer.track.face_crop import subject_point
from facetransfer.track.video_detect import detect_video

BACKGROUND = "960,100"
#: "(x, y)" of each face the refusal names, near the two people's faces
_CENTRES = re.compile(r"centred at \((\d+), (\d+)\), \((\d+), (\d+)\)")


@pytest.fixture(scope="module")
def photo(data_dir):
    return data_dir / "stills" / "breakingbad.jpg"


def _faces_named(line: str) -> list[tuple[int, int]]:
    m = _CENTRES.search(line)
    assert m, line
    xs = [int(v) for v in m.groups()]
    return sorted(zip(xs[::2], xs[1::2]))


def _two_people(faces):
    (xl, yl), (xr, yr) = faces
    assert abs(xl - 758) < 60 and abs(yl - 335) < 60 and abs(xr - 1428) < 60 \
        and abs(yr - 295) < 60, faces


def test_track_refuses_a_point_on_the_background_of_a_photo(photo, quick_model_path,
                                                             tmp_path, capsys):
    """One line, exit 2, no track; a point on or near either face is followed as before."""
    out = tmp_path / "t.npz"
    code = main(["track", str(photo), "--model", str(quick_model_path), "--face", BACKGROUND,
                 "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert len(err) == 1 and f"no face found at or near the point {BACKGROUND} in {photo}: " \
        "2 faces found" in err[0], err
    assert "Traceback" not in err[0]
    _two_people(_faces_named(err[0]))
    # a point on a face, or beside it (on the hair, within the face's size of its centre),
    # follows that face; left / right (a place, not pixels) the face nearest that edge
    for said, right in (("1428,295", True), ("758,335", False), ("870,250", False),
                        ("left", False), ("right", True)):
        det = detect_video(photo, subject=subject_point(said, (1920, 1080)), workers=1)[0]
        x = float(np.nanmean(det.points[0, :, 0]))
        assert det.found.all() and (x > 1100) == right, (said, x)


def test_transfer_refuses_a_target_face_on_the_background(photo, data_dir, quick_model_path,
                                                          tmp_path, capsys):
    out = tmp_path / "o.png"
    code = main(["transfer", "--target", str(photo), "--target-face", BACKGROUND,
                 "--expression-from", str(data_dir / "video" / "driving_d6.mp4"),
                 "--max-frames", "2", "--model", str(quick_model_path), "--out", str(out),
                 "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert len(err) == 1 and f"the point {BACKGROUND} in {photo}" in err[0], err


def test_a_clip_is_refused_on_the_frame_where_the_face_is_chosen(photo, tmp_path):
    """Frames of a clip: the first frame where a face is found is where the point chooses; the
    same rule (a clip of the photo, its first frame empty)."""
    from facetransfer.io.video import VideoOptions, write_video

    still = cv2.imread(str(photo))[..., ::-1]
    frames = np.stack([np.zeros_like(still)] + [still] * 3)
    path = tmp_path / "two.mkv"
    write_video(path, frames, 25.0, options=VideoOptions(crf=0))
    with pytest.raises(TrackError, match=rf"the point {BACKGROUND} in {re.escape(str(path))}"
                                         r": 2 faces found"):
        detect_video(path, subject=subject_point(BACKGROUND, (1920, 1080)), workers=1)
    det = detect_video(path, subject=subject_point("1428,295", (1920, 1080)), workers=1)[0]
    assert det.found[1:].all() and (np.nanmean(det.points[1:, :, 0], axis=1) > 1100).all()
