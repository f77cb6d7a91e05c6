"""Faults found by walk52 (phone footage) in what ``transfer`` and ``puppet`` draw, mended by
helper fix52: the mouth's colours on a dark target, the eyeballs' fill of an eye turned into
its corner, the puppet's note of the frames where the face was lost."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))

from facetransfer.track import Track  # noqa: E402
from test_transfer_cli import clips, run  # noqa: E402,F401  (a fixture)


def test_puppet_says_which_frames_it_holds_where_the_face_was_lost(clips, quick_model_path,
                                                                   tmp_path, capsys):
    """``puppet`` of a clip whose face leaves the picture (walk52's ``leave.mp4``): the frames
    where the face was lost show the nearest tracked frame's head, which ``export`` says in a
    note and the puppet said nothing of. Now it prints the same note, one line naming them, for
    ``puppet VIDEO --track`` and ``puppet TRACK.npz``; none where no frame is lost."""
    track = Track.load(clips["source_track"])
    lost = np.zeros(track.n_frames, bool)
    lost[[2, 3, 5]] = True
    lost_path = tmp_path / "lost.npz"
    dataclasses.replace(track, lost=lost).save(lost_path)
    note = ("note: the face is lost in frames 2-3, 5: the puppet holds the nearest tracked "
            "frame's head there")
    for argv in (["puppet", clips["source"], "--track", lost_path],
                 ["puppet", lost_path]):
        code, out, err = run([*argv, "--model", quick_model_path, "--identity", "id04",
                              "--no-progress", "--out", tmp_path / "p.mp4", "--overwrite"],
                             capsys)
        assert code == 0, err
        lines = out.strip().splitlines()
        assert lines[-1] == note, out
        assert sum("the face is lost" in line for line in lines) == 1, out
    code, out, err = run(["puppet", clips["source"], "--track", clips["source_track"],
                          "--model", quick_model_path, "--identity", "id04", "--no-progress",
                          "--out", tmp_path / "q.mp4"], capsys)
    assert code == 0, err
    assert "the face is lost" not in out, out


def _mouth_scene(face_level: int, source_level: int):
    """A face of one level (the target's skin), the source's mouth: its skin ``source_level``
    and its lips 0.6 of it, a disk pasted inside a ring of skin compared."""
    H, W = 80, 100
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(yy - 40, xx - 50)
    face_img = np.full((H, W, 3), face_level, np.uint8)
    mouth_img = np.full((H, W, 3), source_level, np.uint8)
    mask, ring = r < 15, (r >= 15) & (r < 25)
    mouth_img[mask] = np.array([0.6, 0.4, 0.4]) * source_level
    return face_img, np.ones((H, W), bool), mouth_img, mask, ring


def test_the_mouth_takes_a_dark_targets_exposure():
    """Onto a dark target (walk52's ``dark.mp4``: every level times 0.12) the source's mouth
    needs a gain of ~0.12 to the face's skin; clipped at the range's 0.4 it was pasted at over
    three times the face's level, a bright mouth on a dark face. Now the range is widened by
    the frames' exposure: the lips come out at the target's level (0.12 of the source's), and
    onto a face of the source's level nothing changes (the gains as they were)."""
    from facetransfer import mouth

    face_img, face_mask, mouth_img, mask, ring = _mouth_scene(24, 200)
    out = mouth.blend_mouth(face_img.copy(), face_img.copy(), face_mask, mouth_img, mask, ring,
                            0.0)
    lips = out[mask].astype(float).mean(0)
    want = np.array([0.6, 0.4, 0.4]) * 24
    assert np.abs(lips - want).max() < 2.0, lips
    assert mouth.mouth_gain_range(face_img, mouth_img, ring)[0] < 0.12 * 0.5
    face_img, face_mask, mouth_img, mask, ring = _mouth_scene(200, 200)
    assert mouth.mouth_gain_range(face_img, mouth_img, ring) == mouth.MOUTH_GAIN_RANGE


def _turned_eye(iris_x: int):
    """An eye's opening (an ellipse, 61 x 21 pixels, on skin) with the sclera and an iris of
    radius 9 centred at column ``iris_x`` (the opening spans 20-80)."""
    from test_eyeballs import IRIS, SCLERA, SKIN

    yy, xx = np.mgrid[0:60, 0:100]
    img = np.zeros((60, 100, 3), np.uint8)
    img[:] = SKIN
    opening = ((xx - 50) / 30.5) ** 2 + ((yy - 30) / 10.5) ** 2 <= 1.0
    img[opening] = SCLERA
    img[opening & (np.hypot(xx - iris_x, yy - 30) <= 9)] = IRIS
    return img, opening


def test_the_eyeball_beyond_an_iris_in_its_corner_is_sclera():
    """A reference frame whose eye is turned fully into its corner (walk52: ``transfer --target
    orig.mp4 --expression-from face_2.mp4 --max-frames 30``, whose open-eyed frame looks hard
    to the side): the eyeball under the lids was continued from the opening's nearest pixel,
    the iris beyond that corner, and the eye turned back to the new gaze showed it as a dark
    grey blob over that half. Now beyond the iris along the eye it is the sclera; above and
    below the iris, the iris still (its top under the lid); an eye looking ahead is filled as
    before."""
    from facetransfer import eyeballs
    from test_eyeballs import IRIS, SCLERA

    img, opening = _turned_eye(iris_x=27)                  # the iris against the left corner
    out = eyeballs.extend_eyeballs(img, opening, grow=8)
    beyond = out[28:33, 13:18].reshape(-1, 3).astype(int)  # left of the corner (at column 20)
    assert np.abs(beyond - SCLERA).max() <= 3, beyond
    above = out[17:19, 26:29].reshape(-1, 3).astype(int)   # over the iris, under the lid
    assert np.abs(above - IRIS).max() == 0, above
    right = out[28:33, 83:87].reshape(-1, 3).astype(int)   # the other corner: sclera as before
    assert np.abs(right - SCLERA).max() == 0, right
    img, opening = _turned_eye(iris_x=50)                  # looking ahead
    before = _nearest_fill(img, opening, grow=8)
    np.testing.assert_array_equal(eyeballs.extend_eyeballs(img, opening, grow=8), before)


def _nearest_fill(img, opening, grow: int, rim: int = 1):
    """The fill of every pixel within ``grow + rim`` of the opening's core from its nearest
    core pixel (what :func:`facetransfer.eyeballs.extend_eyeballs` did for every eye)."""
    import cv2

    core = cv2.erode(opening.view(np.uint8), np.ones((3, 3), np.uint8), iterations=rim)
    dist, label = cv2.distanceTransformWithLabels((core == 0).view(np.uint8), cv2.DIST_L2, 5,
                                                  labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero((dist > 0) & (dist <= grow + rim))
    src = np.argwhere(core != 0)[label[ys, xs] - 1]
    out = img.copy()
    out[ys, xs] = img[src[:, 0], src[:, 1]]
    return out
