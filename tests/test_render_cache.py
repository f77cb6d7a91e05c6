"""The render cache of transfer (facetransfer.render_cache): the key of a render and the
folders of unfinished renders."""

import dataclasses
import os

import numpy as np
import pytest

from facetransfer import render_cache as rc
from facetransfer.io import video_parts
from facetransfer.io.video import VideoOptions
from facetransfer.rewrite_options import RewriteOptions
from facetransfer.track.result import Track
from facetransfer.transfer_plan import TransferPlan


class _Model:
    def __init__(self, h):
        self.content_hash = h


def _track(n=4, info=None):
    return Track(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.ones(n), translation=np.zeros((n, 2)),
                 weights={"identity": np.ones((n, 2)), "expression": np.zeros((n, 3))},
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash="m", mode_names=("identity", "expression"),
                 info=info or {})


def _plan(frames=None, **changes):
    frames = np.zeros((4, 48, 64, 3), np.uint8) if frames is None else frames
    plan = TransferPlan(frames, 25.0, _track(), _track(), frames, _track(), np.arange(4), {}, {})
    return dataclasses.replace(plan, **changes)


@pytest.fixture
def on(tmp_path, monkeypatch):
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def test_the_key_holds_everything_the_frames_depend_on(on, monkeypatch):
    model, opts = _Model("a"), RewriteOptions()
    k = rc.render_key(_plan(), model, opts, None)
    assert k == rc.render_key(_plan(), model, opts, None)
    # a track's info holds timings: not part of the key
    assert k == rc.render_key(_plan(new_track=_track(info={"seconds": 1.5})), model, opts, None)
    moved = _track()
    moved.translation[2, 0] = 0.5
    pixel = np.zeros((4, 48, 64, 3), np.uint8)
    pixel[3, 16, 5, 1] = 1  # row 16: a row of the digest
    others = [rc.render_key(_plan(new_track=moved), model, opts, None),
              rc.render_key(_plan(target_frames=pixel), model, opts, None),
              rc.render_key(_plan(mouth_index=np.array([0, 0, 1, 2])), model, opts, None),
              rc.render_key(_plan(fps=30.0), model, opts, None),
              rc.render_key(_plan(), _Model("b"), opts, None),
              rc.render_key(_plan(), model, opts.with_(texture="constant"), None),
              rc.render_key(_plan(), model, opts, VideoOptions(crf=20)),
              rc.render_key(_plan(), model, opts, None, images=True)]
    assert len({k, *others}) == 9
    monkeypatch.setattr(rc, "code_fingerprint", lambda: "another renderer")
    assert rc.render_key(_plan(), model, opts, None) != k
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    assert rc.render_key(_plan(), model, opts, None) is None


def test_unfinished_renders_beyond_the_newest_are_removed(on, monkeypatch):
    import fcntl

    monkeypatch.setattr(rc, "KEEP", 2)
    first = rc.parts_folder("k1")
    busy = os.open(first / "lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(busy, fcntl.LOCK_EX)  # another process writes k1's parts
    try:
        assert video_parts.folder_in_use(first)
        os.utime(first, (1000, 1000))
        for i, key in enumerate(("k2", "k3")):
            os.utime(rc.parts_folder(key), (1001 + i, 1001 + i))
        rc.parts_folder("k4")
        # k4 (current) and k3 (the newest other) kept, k2 removed, k1 is in use
        assert sorted(p.name for p in rc.render_dir().iterdir()) == ["k1", "k3", "k4"]
    finally:
        os.close(busy)
    assert not video_parts.folder_in_use(first)
    rc.parts_folder("k3")
    assert sorted(p.name for p in rc.render_dir().iterdir()) == ["k3", "k4"]
