"""Cuts in an edited clip (facetransfer.track.shots): found from the picture's change and the
flow's failure, each shot captured on its own with its own identity."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.io.video import read_video
from facetransfer.track.detect import ClipDetections, picture_change
from facetransfer.track.shots import MIN_SHOT, shot_spans, shot_starts


def _det(n: int, cuts=(), *, flow_ok=(), faces=True) -> ClipDetections:
    """Detections of ``n`` frames whose picture changes by 2 levels a frame and by 50 at
    ``cuts``, the flow failing there unless in ``flow_ok``."""
    rng = np.random.default_rng(0)
    P = rng.uniform(100, 200, (n, 68, 2)) if faces else np.full((n, 68, 2), np.nan)
    F = rng.normal(0, 0.5, (n, 68, 2))
    change = np.full(n, 2.0, np.float32) + rng.uniform(-0.5, 0.5, n).astype(np.float32)
    change[0] = np.nan
    F[0] = np.nan
    for t in cuts:
        change[t] = 50.0
        if t not in flow_ok:
            F[t] = np.nan
    return ClipDetections(P, F, change=change)


def test_a_cut_is_a_sudden_change_where_the_flow_fails():
    assert shot_starts(_det(60, [30])) == [30]
    assert shot_starts(_det(60, [20, 40])) == [20, 40]
    assert shot_starts(_det(60, [30], flow_ok=[30])) == []          # a face still followed
    assert shot_starts(_det(60, [30], faces=False)) == [30]         # no face: the picture only
    assert shot_starts(_det(60, [30, 32])) == []                    # a flash: in and out
    assert shot_starts(_det(60, [MIN_SHOT - 1])) == []              # too short a shot
    assert shot_starts(_det(60)) == [] and shot_starts(ClipDetections.from_points(
        np.zeros((60, 68, 2)))) == []                               # not measured
    assert shot_spans([20, 40], 60) == [(0, 20), (20, 40), (40, 60)]


def test_the_picture_change_of_two_frames():
    a = np.full((64, 96), 100, np.uint8)
    b = a.copy()
    b[:, :48] = 140
    assert picture_change(a, a) == 0.0
    assert picture_change(a, b) == pytest.approx(20.0)


@pytest.fixture(scope="module")
def edited(data_dir):
    """40 frames of driving_d6 cut to 40 of WDA_KatieHill_000 (480x480 both)."""
    a = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=40)[0]
    b = read_video(data_dir / "video" / "WDA_KatieHill_000.mp4", max_frames=40)[0]
    b = np.stack([cv2.resize(f, (480, 480), interpolation=cv2.INTER_AREA) for f in b])
    return a, b


def test_each_shot_of_an_edited_clip_is_captured_with_its_own_identity(edited, arkit_model,
                                                                       caplog):
    """The cut is found; each shot's identity is the one the shot captured alone gets, and the
    activations too (before: one identity for both people)."""
    from facetransfer.track.capture import capture_video

    a, b = edited
    with caplog.at_level("WARNING"):
        both = capture_video(np.concatenate([a, b]), arkit_model, workers=1)
    assert "cuts to another shot at frame 40" in caplog.text
    assert both.shot_starts == (40,) and not both.lost.any()
    ident = both.weights["identity"]
    assert np.array_equal(ident[0], ident[39]) and np.array_equal(ident[40], ident[79])
    assert np.abs(ident[0] - ident[40]).max() > 0.05
    for part, sl in ((a, slice(0, 40)), (b, slice(40, 80))):
        alone = capture_video(part, arkit_model, workers=1)
        assert np.abs(ident[sl][0] - alone.weights["identity"][0]).max() < 0.01
        assert np.abs(both.blendshapes[sl] - alone.blendshapes).mean() < 0.03


def test_a_clip_that_opens_on_black_is_no_cut_only_lost_until_the_face(edited, arkit_model,
                                                                         caplog):
    """30 black frames, then the face: its frames before are lost, the rest captured as the
    face's frames alone, and no cut to "another shot" is said (there is one person)."""
    from facetransfer.track.capture import capture_video

    a = edited[0]
    with caplog.at_level("WARNING"):
        tr = capture_video(np.concatenate([np.zeros_like(a[:30]), a]), arkit_model, workers=1)
    assert "cuts to another shot" not in caplog.text
    assert tr.lost[:30].all() and not tr.lost[30:].any()
    alone = capture_video(a, arkit_model, workers=1)
    assert np.abs(tr.blendshapes[30:] - alone.blendshapes).mean() < 0.03
    # an identity held fixed (a chunk of ``batch track --chunk``) is the face's, black or not
    held = alone.weights["identity"][0] * 0.9
    fixed = capture_video(np.concatenate([np.zeros_like(a[:30]), a]), arkit_model, workers=1,
                          fixed={"identity": held})
    np.testing.assert_array_equal(fixed.weights["identity"][30:], np.tile(held, (len(a), 1)))


def test_a_two_shot_target_is_rewritten_as_its_shots_alone(quick_model, tmp_path_factory):
    """Each shot of an edited target is rendered as a clip of its own (its own reference
    frames): the frames equal those of each shot rewritten alone; the shots survive a track
    file and a run of frames taken."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_transfer_rewrite import render_clip

    from facetransfer.rewrite_clip import RenderRun, rewrite_frames
    from facetransfer.texture import default_face_texture
    from facetransfer.topology import mesh_topology
    from facetransfer.track import Track
    from facetransfer.track.project import take_frames
    from facetransfer.track.shots import joined_shots

    m = quick_model
    topo, tex = mesh_topology(m), default_face_texture(m, 256)
    smile = [m.training_weights("expression", e) for e in ("smile", "open", "smile", "neutral")]
    fa, ta = render_clip(m, topo, tex, "id01", smile, [0, 4, 8, 4], seed=1)
    fb, tb = render_clip(m, topo, tex, "id03", smile[::-1], [-4, 0, 4, 8], seed=2)
    both = joined_shots([ta, tb], [(0, 4), (4, 8)])
    assert both.shot_starts == (4,)
    path = tmp_path_factory.mktemp("shots") / "t.npz"
    both.save(path)
    both = Track.load(path)
    assert both.shot_starts == (4,) and take_frames(both, np.arange(2, 7)).shot_starts == (2,)
    assert take_frames(both, np.array([0, 5])).shot_starts == ()
    frames = np.concatenate([fa, fb])
    new = both                                     # the clip's own performance
    one = RenderRun(workers=1)
    joined = [r.image for r in rewrite_frames(frames, both, new, m, topo=topo, run=one)]
    alone = [r.image for f, t in ((fa, ta), (fb, tb))
             for r in rewrite_frames(f, t, t, m, topo=topo, run=one)]
    assert all(np.array_equal(a, b) for a, b in zip(joined, alone))
    later = [r.image for r in rewrite_frames(frames, both, new, m, topo=topo,
                                             run=RenderRun(workers=1, start=5))]
    assert all(np.array_equal(a, b) for a, b in zip(later, alone[5:]))


def test_a_fixed_identity_is_the_first_shots(edited, arkit_model):
    """An identity held fixed (a later chunk of ``batch track --chunk``) is the face the clip
    starts with: the shots after a cut get their own."""
    from facetransfer.track.capture import capture_video

    from facetransfer.track.solver import Prior

    a, b = edited
    w = Prior.from_model(arkit_model, "identity").mean          # the model's mean face
    both = capture_video(np.concatenate([a, b]), arkit_model, workers=1,
                         fixed={"identity": w})
    ident = both.weights["identity"]
    assert np.allclose(ident[:40], w)
    assert np.abs(ident[40] - w).max() > 0.05 and np.array_equal(ident[40], ident[79])


def test_a_chunk_after_a_cut_it_cannot_see_gets_its_own_identity(edited, arkit_model,
                                                                 tmp_path, caplog):
    """``batch track --chunk``: a later chunk is captured with the first chunk's identity where
    it begins on that person, and with its own where the clip cut to another person in an
    earlier chunk (before: the first person's identity, fitted to the other face)."""
    from facetransfer.batch import jobs as J
    from facetransfer.batch.chunks import Chunk
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.io.video import VideoOptions, write_video
    from facetransfer.track.capture import capture_video
    from facetransfer.track.settings import TrackerSettings

    a, b = edited
    path = tmp_path / "edited.mkv"
    write_video(path, np.concatenate([a, b]), 25.0, options=VideoOptions(crf=0))
    job, out, opt = ClipJob("edited", str(path)), str(tmp_path / "e.npz"), TrackerSettings()
    first = J.track_chunk(job, Chunk(0, 0, 30), out, arkit_model, opt)
    w = first.track.weights["identity"][0]
    same = J.track_chunk(job, Chunk(1, 10, 40), out, arkit_model, opt, first).track
    assert np.array_equal(same.weights["identity"], np.tile(w, (30, 1)))
    with caplog.at_level("WARNING"):
        other = J.track_chunk(job, Chunk(2, 50, 80), out, arkit_model, opt, first).track
    assert "frames 50-79 begin on another face than the clip's first" in caplog.text
    alone = capture_video(read_video(path, start=50, stop=80)[0], arkit_model, workers=1)
    assert np.abs(other.weights["identity"][0] - w).max() > 0.1
    assert np.allclose(other.weights["identity"], alone.weights["identity"])


def test_a_cut_inside_a_later_chunk_is_named_by_the_clips_frame_numbers(edited, arkit_model,
                                                                       tmp_path, caplog):
    """``batch track --chunk`` of a plate numbered from 1001 whose cut is at its frame 1041:
    the chunk of frames 1026-1055 (rows 25-54) says the cut at 1041, as ``track`` of the whole
    plate does (before: 1016, counted from the chunk's own first frame as if it were the
    plate's first); a later chunk with no face names the frames it searched by the clip's
    numbers too."""
    from facetransfer.batch import jobs as J
    from facetransfer.batch.chunks import Chunk
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.errors import VideoError
    from facetransfer.track.settings import TrackerSettings

    a, b = edited
    (tmp_path / "plate").mkdir()
    for k, f in enumerate(np.concatenate([a, b]), start=1001):
        cv2.imwrite(str(tmp_path / "plate" / f"e.{k}.png"), f[..., ::-1])
    job = ClipJob("edited", str(tmp_path / "plate" / "e.####.png"))
    out, opt = str(tmp_path / "e.npz"), TrackerSettings()
    first = J.track_chunk(job, Chunk(0, 0, 25), out, arkit_model, opt)
    with caplog.at_level("WARNING"):
        cut = J.track_chunk(job, Chunk(1, 25, 55), out, arkit_model, opt, first).track
    assert cut.shot_starts == (15,)                 # the chunk's row 15: the clip's row 40
    assert "cuts to another shot at frame 1041:" in caplog.text, caplog.text
    for k in range(1056, 1066):                      # a chunk of grey frames: no face
        cv2.imwrite(str(tmp_path / "plate" / f"e.{k}.png"), np.full((480, 480, 3), 128, np.uint8))
    with pytest.raises(VideoError, match=r"no face found in .*e\.####\.png \(searched frames "
                                         r"1056-1065\)"):
        J.track_chunk(job, Chunk(2, 55, 65), out, arkit_model, opt, first)


def test_the_optical_flow_trackers_later_chunk_names_the_clips_frame_numbers(
        edited, arkit_model, tmp_path, caplog):
    """``batch track --chunk --tracker klt`` of a plate numbered from 1001: a later chunk (rows
    10-19) that opens on two grey frames says its first face is at the plate's frame 1013, and
    one of grey frames only names the frames it searched, 1011-1020 (before: 1003 and
    1001-1010, counted from the chunk's own first frame as if it were the plate's first)."""
    from facetransfer.batch import jobs as J
    from facetransfer.batch.chunks import Chunk
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.errors import VideoError
    from facetransfer.track.settings import TrackerSettings

    a, _ = edited
    grey = np.full((480, 480, 3), 128, np.uint8)
    (tmp_path / "plate").mkdir()
    frames = [grey] * 12 + list(a[:8])
    for k, f in enumerate(frames, start=1001):
        cv2.imwrite(str(tmp_path / "plate" / f"g.{k}.png"), f[..., ::-1])
    job = ClipJob("grey", str(tmp_path / "plate" / "g.####.png"))
    opt = TrackerSettings("klt")
    with caplog.at_level("INFO", logger="facetransfer.track.tracker"):
        J.track_chunk(job, Chunk(1, 10, 20), str(tmp_path / "g.npz"), arkit_model, opt)
    assert "first face found at frame 1013" in caplog.text, caplog.text
    for k in range(1013, 1021):
        cv2.imwrite(str(tmp_path / "plate" / f"g.{k}.png"), grey)
    with pytest.raises(VideoError, match=r"no face found in .*g\.####\.png \(searched frames "
                                         r"1011-1020\)"):
        J.track_chunk(job, Chunk(1, 10, 20), str(tmp_path / "g2.npz"), arkit_model, opt)


def test_one_persons_shots_share_an_identity_and_a_gap_holds_its_nearest_frames(
        edited, arkit_model, caplog):
    """The same person before and after 12 black frames (a cut to black and back): one
    identity through the clip, the first shot's (before: each shot its own, 0.1 apart, and the
    exports carry the first only); the gap is lost, its first half holding the last frame
    before it and its second half the first after it (before: all of it the shot before's,
    the head snapping at the gap's end). Another person's shot keeps its own (above)."""
    from facetransfer.track.capture import capture_video

    a = edited[0]
    clip = np.concatenate([a[:24], np.zeros_like(a[:12]), a[16:40]])
    with caplog.at_level("WARNING"):
        tr = capture_video(clip, arkit_model, workers=1)
    assert tr.shot_starts and tr.lost[24:36].all() and not tr.lost[:24].any()
    ident = tr.weights["identity"]
    np.testing.assert_array_equal(ident, np.tile(ident[0], (len(clip), 1)))
    np.testing.assert_array_equal(tr.rotation[24:30], np.tile(tr.rotation[23], (6, 1, 1)))
    np.testing.assert_array_equal(tr.rotation[30:36], np.tile(tr.rotation[36], (6, 1, 1)))
    np.testing.assert_array_equal(tr.blendshapes[30:36], np.tile(tr.blendshapes[36], (6, 1)))
