"""Review of the fifty-sixth session's saved performance and mouth texture (review56b): a
performance's mark is shown by ``probe`` and warned of by ``texture lift``; the mouth
texture's progress bar counts the frames ``tex_size="auto"`` lifts."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np

from facetransfer.cli.main import main
from facetransfer.track import Track
from facetransfer.track.result import MADE_BY_TRANSFER


def test_probe_says_a_track_file_is_a_saved_performance(arkit_model, make_arkit_track,
                                                       tmp_path, capsys):
    """A transfer's saved performance names its target as ``source``: ``probe`` said "a
    track ... made from target.mp4" and nothing else, the very reading that has it refused as
    ``--target-track``. Now a line says what it is, and the JSON has ``made_by``."""
    track, _, _ = make_arkit_track(arkit_model, 10, fps=25.0)
    track = dataclasses.replace(track, source="target.mp4")
    track.save(tmp_path / "clip.npz")
    dataclasses.replace(track, made_by=MADE_BY_TRANSFER).save(tmp_path / "new.npz")
    assert main(["probe", str(tmp_path / "clip.npz")]) == 0
    out = capsys.readouterr().out
    assert "performance" not in out
    assert main(["probe", str(tmp_path / "new.npz")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == ("  a transfer's saved performance (--save-track: the source's "
                         "expressions on the target's head): give it as --performance, or to "
                         "export, view, puppet; not a track of the clip it was made from "
                         "(refused as --target-track)")
    assert main(["probe", str(tmp_path / "new.npz"), str(tmp_path / "clip.npz"), "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    assert [f["made_by"] for f in facts] == [MADE_BY_TRANSFER, None]


def test_texture_lift_through_a_saved_performance_warns(tmp_path, caplog):
    """``texture lift target.mp4 --track new.npz``: the performance names the target as its
    source (no "made from another video" warning), yet its meshes are the source's
    expressions, not the target's face: lifted silently before, now warned of (a warning,
    not a refusal: the transfer's output video is what the performance does show)."""
    from facetransfer.model import build_model
    from facetransfer.synth import load_truth, make_clip, random_performance, write_clip
    from test_texture_track import _cap_dataset

    model = build_model(_cap_dataset(), {"identity": 3, "expression": 3})
    model.save(tmp_path / "m.npz")
    clip = make_clip(model, random_performance(model, 3, seed=0, size=(96, 80)))
    write_clip(clip, tmp_path / "target.mp4")
    t = load_truth(tmp_path / "target.truth.npz")
    n = len(t.scale)
    track = Track(fps=t.fps, frame_size=t.frame_size, rotation=t.rotation, scale=t.scale,
                  translation=t.translation, weights=t.weights, landmarks2d=np.zeros((n, 68, 2)),
                  confidence=np.ones(n), lost=np.zeros(n, bool), model_hash=model.content_hash,
                  mode_names=model.mode_names, source=str(tmp_path / "target.mp4"))
    track.save(tmp_path / "clip.npz")
    dataclasses.replace(track, made_by=MADE_BY_TRANSFER).save(tmp_path / "new.npz")
    argv = ["texture", "lift", str(tmp_path / "target.mp4"), "--model", str(tmp_path / "m.npz"),
            "--size", "32", "--overwrite", "--out", str(tmp_path / "o.png"), "--track"]
    with caplog.at_level(logging.WARNING):
        assert main(argv + [str(tmp_path / "clip.npz")]) == 0
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    with caplog.at_level(logging.WARNING):
        assert main(argv + [str(tmp_path / "new.npz")]) == 0
    said = " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    assert f"track {tmp_path / 'new.npz'} is a performance made by transfer" in said
    assert "not a track of target.mp4" in said
    assert (tmp_path / "o.png").is_file()                      # lifted all the same


def test_the_mouth_bar_counts_the_frames_auto_lifts(monkeypatch):
    """``tex_size="auto"`` lifts fewer frames than 120 where the mouth's square is large (a
    4K face: 83 at 448²); the transfer's bar had a total of min(120, frames) and stopped
    short (83/120). Its total is now the count the lifting announces (``on_frames``)."""
    from types import SimpleNamespace

    from facetransfer import video_transfer as vt

    def mouth_function(model, *, progress=None, on_frames=None, **kw):
        if on_frames is not None:
            on_frames(83)
        for _ in range(83):
            if progress is not None:
                progress(1)
        return "fn"

    bars = []

    class Bar:
        def __init__(self, desc, total):
            self.desc, self.total, self.n, self.closed = desc, total, 0, False
            bars.append(self)

        def update(self, n):
            self.n += n

        def close(self):
            self.closed = True

    plan = SimpleNamespace(texture_frames=np.zeros((200, 2, 2, 3), np.uint8), n_frames=200,
                           mouth_function=mouth_function)
    assert vt._lift_mouth(plan, None, Bar) == "fn"
    assert [(b.desc, b.total, b.n, b.closed) for b in bars] == [("mouth texture", 83, 83, True)]
    assert vt._lift_mouth(plan, None, None) == "fn" and len(bars) == 1    # no bar asked for


def test_mouth_texture_function_announces_the_frames_it_lifts(quick_model):
    """``on_frames`` is called once, before the first frame, with the frames lifted."""
    from facetransfer.texture.face import mouth_texture_function
    from test_mouth_res56 import _scene

    frames, track, topo, _ = _scene(quick_model, 64, 4.0)
    seen = []
    fn = mouth_texture_function(quick_model, frames, track, topo, tex_size="auto",
                                on_frames=lambda n: seen.append(("total", n)),
                                progress=lambda n: seen.append(("step", n)))
    assert fn.frames.size == len(frames)
    assert seen == [("total", len(frames))] + [("step", 1)] * len(frames)


def test_the_funnel_gate_asks_nothing_of_a_paper_model_and_skips_lost_frames(quick_model,
                                                                            arkit_model):
    """review56b (checked, not mended): a model without ARKit activations (the paper's
    bilinear model) has no funnel to hold (None); a lost frame's NaN points gate nothing."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track import capture_points
    from facetransfer.track.capture import CaptureOptions, funnel_ridges
    from facetransfer.track.capture_points import Shape

    opt = CaptureOptions()
    pts = np.zeros((3, 68, 2))
    pts[:, 36], pts[:, 45] = (0.0, 0.0), (10.0, 0.0)       # lips shut (gap 0) in frames 0, 2
    pts[1] = np.nan                                          # frame 1 lost
    paper = Shape(quick_model, np.asarray(quick_model.default_weights()["identity"]),
                  capture_points.sampler(quick_model), opt)
    assert funnel_ridges(paper, pts, opt) is None
    shape = Shape(arkit_model, np.asarray(arkit_model.default_weights()["identity"]),
                  capture_points.sampler(arkit_model), opt)
    k = int(np.flatnonzero(shape.used == ARKIT_NAMES.index("mouthFunnel"))[0])
    np.testing.assert_allclose(funnel_ridges(shape, pts, opt)[:, k], [1.0, 0.0, 1.0])


def test_made_by_none_is_a_clips_track_not_one_made_by_none(quick_track, tmp_path):
    """``Track(..., made_by=None)`` (None, as the other optional fields take it) was marked
    ``"None"``: saved so, and refused as ``--target-track`` "a performance made by None"."""
    from facetransfer.transfer_plan import performance_given

    t = dataclasses.replace(quick_track, made_by=None)
    assert t.made_by == ""
    t.save(tmp_path / "t.npz")
    assert Track.load(tmp_path / "t.npz").made_by == ""
    assert performance_given(tmp_path / "t.npz", "--target-track", "target", "t.mp4") is None
