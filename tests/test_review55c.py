"""Review of large54/large55 (``face_scale``) and photoeye55 (a photo's eye room) together
(fifty-fifth session, helper review55c)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from facetransfer import eyeballs, face_scale

from conftest import mean_eye_span, record_scales

SKIN = (150, 105, 85)


def _photo_eyes(width: int, lashes: int):
    """A photo's two eye openings ``width`` px wide (``eye``: -1 outside, 0 and 1 in them)
    in skin, white sclera, a dark iris touching both lids left of the middle, the opening's
    outer ``lashes`` px dark (the lashes and the lid margin, where a track's opening is a
    little off). Returns ``(image, eye, widths)``."""
    h, w = 2 * width, 4 * width
    image = np.empty((h, w, 3), np.uint8)
    image[:] = SKIN
    eye = np.full((h, w), -1, np.int8)
    half = (width // 2, width // 6)
    for e, cx in enumerate((w // 4, 3 * w // 4)):
        m = np.zeros((h, w), np.uint8)
        cv2.ellipse(m, (cx, h // 2), half, 0, 0, 360, 1, -1)
        m = m.astype(bool)
        eye[m] = e
        image[m] = (235, 232, 228)
        iris = np.zeros((h, w), np.uint8)
        cv2.circle(iris, (cx - width // 8, h // 2), width // 5, 1, -1)
        image[m & iris.astype(bool)] = (60, 45, 35)
        rim = m & (cv2.distanceTransform(m.view(np.uint8), cv2.DIST_L2, 5) <= lashes)
        image[rim] = (35, 28, 25)
    return image, eye, np.array([width, width], np.float64)


def test_a_larger_photos_eye_room_is_measured_inside_the_rim_the_fill_redoes():
    """:func:`facetransfer.eyeballs.eye_room` measured a photo's iris and sclera inside the
    opening eroded by :data:`~facetransfer.eyeballs.RIM` (1 px), written before large55 grew
    the rim that :func:`~facetransfer.eyeballs.eyeballs_of` redoes with the eye (2 px from eyes
    63 px wide: ``breakingbad.jpg``'s near eye, 64.9 px; 3 px from 105 px). An eye 130 px
    wide (a portrait's, as large55's 1280x1280 clip's, 120 px) with 3 px of lashes on its rim:
    the lashes left in that core joined the iris that touches the lids into one dark part
    spanning the eye, so it had no sclera beside its iris and kept the photo's gaze (room 0);
    measured inside the rim the fill redoes, its iris has the sclera it shows."""
    image, eye, width = _photo_eyes(130, lashes=3)
    room = eyeballs.eye_room(image, eye, width)
    assert (room[:, 2:] > 0).all(), room                      # before: all 0
    assert np.abs(room[:, 0]) == pytest.approx([1.0, 1.0], abs=0.05)   # along the eye
    # a data-folder eye (50 px wide, the rim 1 px) is measured as before
    small, eye_s, width_s = _photo_eyes(50, lashes=1)
    assert (eyeballs.eye_room(small, eye_s, width_s)[:, 2:] > 0).all()


def test_a_run_resumed_mid_shot_takes_the_whole_shots_factor_and_a_cut_its_own(
        arkit_model, monkeypatch):
    """A render continued from a frame in the middle of a shot (``transfer`` resumed through
    the render cache: ``RenderRun.start``) rewrites its frames with the factor of the whole
    shot (:func:`facetransfer.face_scale.shot_scale`), as the uninterrupted run does: its
    frames equal that run's to the bit. Not the factor of the frames left (here 1.249 against
    the shot's 1.275: the blend's erosion 2 px, not 3). After a cut the next shot takes its own
    factor (1.6), not the clip's."""
    from facetransfer.rewrite_clip import RenderRun, rewrite_frames
    from facetransfer.rewrite_options import RewriteOptions
    from conftest import mean_person_track

    model = arkit_model
    topo, V, d = mean_eye_span(model)
    monkeypatch.setattr(face_scale, "FACE_SPAN", 50.0)      # the threshold at a small face
    factors = np.array([1.30, 1.30, 1.249, 1.249, 1.6, 1.6, 1.6, 1.6])
    track = mean_person_track(model, np.zeros((8, 52), np.float32), size=256, scale=10.0)
    track = dataclasses.replace(track, scale=factors * 50.0 / d, shot_starts=(4,))
    rng = np.random.default_rng(5)
    frames = [np.clip(np.asarray(SKIN) + rng.normal(0, 12, (256, 256, 3)), 0, 255)
              .astype(np.uint8) for _ in range(8)]
    seen = record_scales(monkeypatch)
    whole = [r.image for r in rewrite_frames(frames, track, track, model,
                                             options=RewriteOptions(),
                                             run=RenderRun(workers=1))]
    per_frame = len(seen) // 8
    shot = face_scale.shot_scale(V, track, topo.eye_loops, range(4))
    assert shot == pytest.approx(1.2745, abs=5e-3)
    assert seen == pytest.approx([shot] * (4 * per_frame) + [1.6] * (4 * per_frame), abs=5e-3)
    seen.clear()
    resumed = [r.image for r in rewrite_frames(frames, track, track, model,
                                               options=RewriteOptions(),
                                               run=RenderRun(workers=1, start=2))]
    assert seen == pytest.approx([shot] * (2 * per_frame) + [1.6] * (4 * per_frame), abs=5e-3)
    assert len(resumed) == 6
    for k, image in enumerate(resumed, 2):
        assert np.array_equal(image, whole[k]), k
