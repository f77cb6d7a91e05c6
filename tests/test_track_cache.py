"""The track cache of transfer, puppet and demo (facetransfer.track.cache)."""

import logging

import numpy as np
import pytest

from facetransfer.track import cache


class _Model:
    def __init__(self, h):
        self.content_hash = h


@pytest.fixture
def on(tmp_path, monkeypatch):
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    video = tmp_path / "v.mp4"
    video.write_bytes(b"not decoded here")
    return video


def test_the_key_holds_everything_a_track_depends_on(on, tmp_path, monkeypatch):
    k = cache.track_key(on, 10, "capture", None, _Model("a"))
    assert k is not None and k == cache.track_key(str(on), 10, "capture", None, _Model("a"))
    others = [cache.track_key(on, 11, "capture", None, _Model("a")),
              cache.track_key(on, 10, "flow", None, _Model("a")),
              cache.track_key(on, 10, "flow", ("options", 2), _Model("a")),
              cache.track_key(on, 10, "capture", None, _Model("b"))]
    assert len({k, *others}) == 5
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "another tracker")
    assert cache.track_key(on, 10, "capture", None, _Model("a")) != k
    assert cache.track_key(tmp_path / "none.mp4", 10, "capture", None, _Model("a")) is None
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "off")
    assert cache.track_key(on, 10, "capture", None, _Model("a")) is None


def _track(n=4):
    from facetransfer.track.result import Track

    names = ("identity", "expression")
    return Track(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.ones(n), translation=np.zeros((n, 2)),
                 weights={"identity": np.ones((n, 2)), "expression": np.zeros((n, 3))},
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash="m", mode_names=names)


def test_stored_tracks_come_back_and_the_oldest_go(on, monkeypatch):
    monkeypatch.setattr(cache, "KEEP", 2)
    model = _Model("m")
    monkeypatch.setattr(type(_track()), "check_model", lambda self, m: None)
    for i, key in enumerate(("k1", "k2", "k3")):
        cache.partial_path(key).parent.mkdir(parents=True, exist_ok=True)
        cache.partial_path(key).write_bytes(b"progress")
        cache.store_track(key, _track(4 + i))
        assert not cache.partial_path(key).exists()
        import os
        os.utime(cache.track_dir() / f"{key}.npz", (1000 + i, 1000 + i))
    assert sorted(p.name for p in cache.track_dir().iterdir()) == ["k2.npz", "k3.npz"]
    assert cache.cached_track("k3", model).n_frames == 6
    assert cache.cached_track("k1", model) is None and cache.cached_track(None, model) is None


def test_a_damaged_cached_track_is_removed_with_a_warning(on, caplog):
    cache.track_dir().mkdir(parents=True)
    bad = cache.track_dir() / "kx.npz"
    bad.write_bytes(b"PK\x03\x04 damaged")
    with caplog.at_level(logging.WARNING, logger="facetransfer.track.cache"):
        assert cache.cached_track("kx", _Model("m")) is None
    assert not bad.exists() and "removing unreadable cached track" in caplog.text


def test_a_cache_that_cannot_be_written_does_not_fail_the_job(on, tmp_path, monkeypatch,
                                                               caplog):
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder should be")
    with caplog.at_level(logging.WARNING, logger="facetransfer.track.cache"):
        cache.store_track("k", _track())
    assert "could not keep the track in the cache" in caplog.text


def test_a_cache_folder_that_is_a_file_does_not_fail_the_job(on, tmp_path, caplog):
    """The cache's ``tracks`` a file: a capture's progress file there is looked up, removed
    and written as warnings at most (before: "Not a directory" failed transfer and puppet,
    and demo fell back to a landmark-only fit)."""
    from facetransfer.track.detect_checkpoint import DetectionCheckpoint

    cache.track_dir().parent.mkdir(parents=True, exist_ok=True)
    cache.track_dir().write_text("x")
    ck = DetectionCheckpoint(cache.partial_path("k"), "key", every=0.0, best_effort=True)
    with caplog.at_level(logging.WARNING):
        assert ck.load() is None
        ck.remove()
        ck._write({"a": np.zeros(3)})
    assert "could not save the progress" in caplog.text and not ck.due()
    assert cache.track_dir().read_text() == "x"


def test_a_full_cache_disk_does_not_fail_the_job(on, tmp_path, monkeypatch, caplog):
    """A full disk is an OutputError (io.atomic), not an OSError: the cached track and the
    capture's progress file of the cache are warnings; a progress file elsewhere (`track`'s,
    beside its output) still fails."""
    from facetransfer.errors import OutputError
    from facetransfer.track.detect_checkpoint import DetectionCheckpoint
    from facetransfer.track.result import Track

    def full(*a, **k):
        raise OutputError("cannot write x.npz: no space left on the device")

    monkeypatch.setattr(Track, "save", full)
    with caplog.at_level(logging.WARNING):
        cache.store_track("k", _track())
    assert "could not keep the track in the cache (cannot write x.npz: no space left" in \
        caplog.text
    import facetransfer.track.checkpoint as ckmod

    monkeypatch.setattr(ckmod, "atomic_path", full)
    arrays = {"a": np.zeros(3)}
    kept = DetectionCheckpoint(tmp_path / "p.npz", "key", every=0.0, best_effort=True)
    assert kept.due()
    with caplog.at_level(logging.WARNING):
        kept._write(arrays)
    assert "could not save the progress to" in caplog.text and "no space left" in caplog.text
    assert not kept.due() and kept.saves == 0
    kept._write(arrays)  # no second attempt, no second warning
    assert caplog.text.count("could not save the progress") == 1
    strict = DetectionCheckpoint(tmp_path / "q.npz", "key", every=0.0)
    with pytest.raises(OutputError, match="no space left"):
        strict._write(arrays)


def test_a_landmark_fits_key_follows_its_points_file(on, tmp_path):
    """The landmark fit reads ``NAME.mediapipe478.npz`` beside the video: a new points file is
    another key."""
    import os

    from facetransfer.track.obtain import _depends

    assert _depends("landmarks", on, None) is None
    pts = tmp_path / "v.mediapipe478.npz"
    pts.write_bytes(b"points")
    first = cache.track_key(on, 10, "landmarks", _depends("landmarks", on, None), _Model("m"))
    st = os.stat(pts)
    os.utime(pts, ns=(st.st_atime_ns, st.st_mtime_ns + 10 ** 9))
    again = cache.track_key(on, 10, "landmarks", _depends("landmarks", on, None), _Model("m"))
    assert first is not None and again is not None and first != again
    assert _depends("flow", on, ("opts",)) == ("opts",) and _depends("capture", on, 1) is None


def test_a_track_detected_every_other_frame_is_kept_apart_and_a_full_one_preferred(
        on, tmp_path, monkeypatch):
    """A capture track whose detector saw one frame of two (a transfer's target) has a key of
    its own; asked for one, the cache gives a track of the same clip detected on every frame
    where it holds one (the better), never the other way round."""
    import dataclasses

    from facetransfer.io.video import write_video
    from facetransfer.track import obtain

    video = tmp_path / "clip.mp4"
    frames = np.zeros((4, 48, 64, 3), np.uint8)
    write_video(video, list(frames), 25.0)
    monkeypatch.setattr(type(_track()), "check_model", lambda self, m: None)
    made = []

    def capture(video, model, frames, fps, max_frames, factory, workers=1, partial=None,
                subject=None, every=1, eyes=False):
        made.append(every)
        return dataclasses.replace(_track(4), translation=np.full((4, 2), float(every)))

    monkeypatch.setattr(obtain, "_capture", capture)

    def get(every):
        return obtain.obtain_track(video, _Model("m"), frames=frames, fps=25.0,
                                   detect_every=every).translation[0, 0]

    assert get(2) == 2 and get(2) == 2 and made == [2]
    assert get(1) == 1 and made == [2, 1]                  # the every-other track not taken
    assert get(2) == 1 and get(1) == 1 and made == [2, 1]  # the full one preferred
    assert obtain._depends("capture", video, None, "left", 2) == "face=left,every=2"
    assert obtain._depends("capture", video, None, None, 2, True) == "every=2,eyes"
    assert obtain._depends("auto", video, None) is None


@pytest.mark.parametrize("kw, said", [({"max_frames": 0}, "max_frames must be >= 1"),
                                      ({"max_frames": -3}, "max_frames must be >= 1"),
                                      ({"detect_every": 0}, "detect_every must be >= 1"),
                                      ({"method": "klt"}, "'flow' here")])
def test_obtain_track_names_a_bad_count_or_method(tmp_path, kw, said):
    """max_frames=0 was said as "video ... has no frames (from frame 0)", detect_every=0 was
    taken for 1, and method="klt" (the track command's name) did not say the library's."""
    from facetransfer.errors import FaceTransferError
    from facetransfer.track import obtain

    with pytest.raises(FaceTransferError, match=said):
        obtain.obtain_track(tmp_path / "none.mp4", _Model("m"), **kw)
