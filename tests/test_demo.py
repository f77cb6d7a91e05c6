"""The demo end to end on a few frames of the real clips (quick model to keep it short)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.demo import run_demo, side_by_side
from facetransfer.rewrite_options import RewriteOptions


def test_side_by_side_layout():
    src = np.full((48, 64, 3), 10, np.uint8)
    tgt = np.full((40, 40, 3), 20, np.uint8)
    res = np.full((40, 40, 3), 30, np.uint8)
    f = side_by_side(src, tgt, res, labels=False)
    assert f.shape == (40, 120, 3)
    np.testing.assert_array_equal(f[:, 40:80], tgt)
    np.testing.assert_array_equal(f[:, 80:], res)


@pytest.mark.slow
def test_demo_end_to_end(data_dir, quick_model, tmp_path):
    from facetransfer.io.video import read_video
    from facetransfer.io.video import has_audio
    from facetransfer.track import Track

    res = run_demo(tmp_path / "out", frames=6, model=quick_model)
    assert res.video.is_file() and res.sheet.is_file() and res.track.is_file()
    frames, fps = read_video(res.video)
    assert frames.shape == (6, 512, 3 * 512, 3) and fps == 25.0
    assert has_audio(res.video)  # the target's audio is kept
    tr = Track.load(res.track)
    assert tr.n_frames == 6 and not tr.lost.all()
    # the result differs from the target only around the face: the top rows are the target's
    tgt, res_ = frames[3, :, 512:1024].astype(int), frames[3, :, 1024:].astype(int)
    assert np.abs(tgt[40:60] - res_[40:60]).mean() < 3
    assert np.abs(tgt[250:350, 180:330] - res_[250:350, 180:330]).mean() > 1
    with pytest.raises(ValueError, match="exists"):
        run_demo(tmp_path / "out", frames=6, model=quick_model, overwrite=False)


@pytest.mark.slow
def test_demo_with_the_mouth_texture_function(data_dir, quick_model, tmp_path):
    """``mouth="function"``: the mouth comes from the texture function lifted from the source;
    it differs from the default (the source frame's own mouth) only around the mouth."""
    from facetransfer.io.video import VideoOptions, read_video
    from facetransfer.track import Track

    # lossless H.264 (CRF 0): the encoder's choices for one panel then do not depend on the
    # others, so the panels compare exactly
    lossless = VideoOptions(crf=0)
    a = run_demo(tmp_path / "a", frames=4, model=quick_model, video_options=lossless)
    b = run_demo(tmp_path / "b", frames=4, model=quick_model,
                 options=RewriteOptions(mouth="function"), video_options=lossless)
    fa, _ = read_video(a.video)
    fb, _ = read_video(b.video)
    ra, rb = fa[:, :, 1024:].astype(int), fb[:, :, 1024:].astype(int)
    np.testing.assert_array_equal(fa[:, :, :1024], fb[:, :, :1024])  # source | target panels
    diff = np.abs(ra - rb).max(axis=-1)        # (4, 512, 512)
    # measured (lossless): 1309 pixels more than 2 levels apart, at most 14 (the old mp4v video
    # counted 2303 above 4 levels, coding noise included)
    changed = np.argwhere(diff > 2)
    assert len(changed) > 500
    # ... around the target's mouth (landmarks 48-67 of its track), nowhere else
    tr = Track.load(a.track)
    mouth = tr.landmarks2d[:4, 48:68].reshape(-1, 2).mean(axis=0)      # (x, y)
    assert np.linalg.norm(changed[:, [2, 1]].mean(axis=0) - mouth) < 30
    assert np.percentile(np.linalg.norm(changed[:, [2, 1]] - mouth, axis=1), 95) < 80
    with pytest.raises(ValueError, match="mouth"):
        run_demo(tmp_path / "c", frames=4, model=quick_model,
                 options=RewriteOptions(mouth="lips"))


@pytest.mark.slow
def test_demo_with_a_take_shows_the_take_on_the_model(data_dir, arkit_model, make_arkit_track,
                                                      tmp_path):
    """A Live Link Face take as the demo's source: it has no pictures, so its panel is the take
    performed by the model's mean face in the target's pose (before: the target's own frames,
    labelled the source, which the judge then compared the result with)."""
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import VideoOptions, read_video

    track, _, _ = make_arkit_track(arkit_model, 12, fps=25.0)
    write_livelink(track, tmp_path / "take.csv")
    res = run_demo(tmp_path / "out", frames=6, model=arkit_model, source=tmp_path / "take.csv",
                   target=data_dir / "video" / "WDA_KatieHill_000.mp4", judge=False,
                   video_options=VideoOptions(crf=0))
    frames, _ = read_video(res.video)
    src, tgt = frames[:, :, :512].astype(int), frames[:, :, 512:1024].astype(int)
    assert np.abs(src - tgt).mean() > 40                # not the target's frames
    corner = src[:, 480:, :40].reshape(-1, 3)           # the puppet's plain background
    assert np.abs(corner - (40, 40, 48)).max() <= 2


def test_the_synthetic_inputs_tracks_record_their_clips_numbering(quick_model, tmp_path):
    """The true tracks of the demo's synthetic clips record their clips' first frame number
    and timecode as tracking does (before: none, and an export of one said it was a track
    made before tracks recorded them)."""
    from facetransfer.demo import synthetic_inputs
    from facetransfer.io.source_facts import SourceFacts
    from facetransfer.track import Track

    _, _, ts, tt = synthetic_inputs(tmp_path, quick_model, n_frames=3, size=64)
    for p in (ts, tt):
        assert Track.load(p).source_facts == SourceFacts(0, None)


def test_demo_seconds_count_the_model_it_loaded_or_built(tmp_path, monkeypatch, capsys):
    """`facetransfer demo`'s "seconds:" line counts the model's loading, the default model's
    first build included: before, a first run on a fresh machine said "model 0.1, ... total
    85.7" after 229 s, the 138 s of the build nowhere (the CLI loads the model before the
    demo's clock starts)."""
    import types

    import facetransfer.demo as demo_mod
    from facetransfer.cli import demo as cli_demo
    from facetransfer.cli.main import main
    from facetransfer.demo import DemoResult

    clock = [1000.0]

    def build(path, will_track, **kw):
        clock[0] += 138.0  # the default model built on first use
        return "model"

    def fake_demo(out, **kw):
        return DemoResult(tmp_path / "demo.mp4", tmp_path / "demo.png",
                          tmp_path / "demo_track.npz", 120, "auto",
                          {"model": 0.1, "render": 50.0, "total": 85.7})

    monkeypatch.setattr(cli_demo, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]),
                        raising=False)
    monkeypatch.setattr(cli_demo, "load_model_and_mediapipe", build)
    monkeypatch.setattr(demo_mod, "run_demo", fake_demo)
    assert main(["demo", "--out", str(tmp_path / "out")]) == 0
    seconds = next(ln for ln in capsys.readouterr().out.splitlines()
                   if ln.startswith("seconds:"))
    assert seconds == "seconds: model 138.1, render 50.0, total 223.7"
