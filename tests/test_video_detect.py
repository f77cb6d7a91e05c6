"""A video's detections in one process or two (facetransfer.track.video_detect, issue 12 speed)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.track import video_detect
from facetransfer.track.detect import ClipDetections
from facetransfer.track.video_detect import (detect_video, finish_split, join_detections,
                                             split_frame)

N = 64          # frames of driving_d9 detected in the tests with MediaPipe


def _dets(n: int, offset: float = 0.0, scores: bool = True) -> ClipDetections:
    rng = np.random.default_rng(int(offset))
    P = rng.uniform(0, 100, (n, 68, 2)) + offset
    fl = rng.normal(0, 1, (n, 68, 2))
    q = rng.uniform(0, 100, (n, 478, 2)).astype(np.float32)
    s = rng.uniform(0, 1, (n, 52)).astype(np.float32) if scores else None
    return ClipDetections(P, fl, q, s)


def test_split_frame_halves_what_is_left_of_a_long_enough_clip():
    assert split_frame(0, 354, 2) == 177
    # a run resumed in this process's part: the split of the run it continues (the child's
    # frames detected as then); resumed in the child's part: the rest halved
    assert split_frame(100, 400, 2) == 200 and split_frame(199, 400, 2) == 200
    assert split_frame(350, 600, 2) == 475 and split_frame(250, 300, 2) is None
    # the first half done, the child's lost: continued here from where the child started
    assert split_frame(200, 400, 2) is None
    assert split_frame(0, 354, 1) is None                      # one worker
    short = video_detect.SPLIT_MIN_FRAMES - 1
    assert split_frame(0, short, 2) is None                    # not worth a second process
    assert split_frame(300, 300 + short, 2) is None


def test_join_detections_keeps_every_array_in_order():
    a, b = _dets(5), _dets(7, offset=1000.0)
    j = join_detections(a, b)
    assert j.n_frames == 12
    for name in ("points", "flow", "points478", "scores"):
        np.testing.assert_array_equal(getattr(j, name)[:5], getattr(a, name))
        np.testing.assert_array_equal(getattr(j, name)[5:], getattr(b, name))
    k = join_detections(a, _dets(3, offset=7.0, scores=False))   # a part without scores
    assert np.isnan(k.scores[5:]).all() and np.array_equal(k.scores[:5], a.scores)


class _Child:
    """Stands in for SplitDetection: returns ``value`` (or raises it) from result()."""

    def __init__(self, value) -> None:
        self.value, self.cancelled, self.polled = value, False, False

    def result(self, poll=None):
        if poll is not None:
            poll(3)
            self.polled = True
        if isinstance(self.value, BaseException):
            raise self.value
        return self.value

    def cancel(self) -> None:
        self.cancelled = True


class _Checkpoint:
    def __init__(self) -> None:
        self.saved = []

    def save(self, det) -> None:
        self.saved.append(det)


def _never(first):
    raise AssertionError("redetect must not be called")


def test_finish_split_joins_the_childs_part():
    first, rest = _dets(10), _dets(6, offset=1.0)   # the same face, other points
    seen = []
    out = finish_split(first, _Child(rest), 10, _never, poll=seen.append)
    assert out.n_frames == 16 and np.array_equal(out.points[10:], rest.points) and seen == [3, 6]


def test_finish_split_when_the_clip_ends_in_the_first_part():
    first, child = _dets(8), _Child(_dets(4))
    assert finish_split(first, child, 10, _never) is first and child.cancelled
    assert finish_split(first, _Child(None), 8, _never) is first   # the child found no frames


def test_finish_split_detects_the_rest_here_when_the_child_failed():
    first, again = _dets(10), _dets(20)
    calls = []

    def redetect(f):
        calls.append(f)
        return again

    assert finish_split(first, _Child(False), 10, redetect) is again and calls == [first]


def test_finish_split_interrupted_saves_the_first_part():
    first, ck = _dets(10), _Checkpoint()
    with pytest.raises(KeyboardInterrupt):
        finish_split(first, _Child(KeyboardInterrupt()), 10, _never, checkpoint=ck)
    assert ck.saved == [first]


def test_finish_split_names_another_face_by_the_plates_frame_number(caplog):
    """The child's part starting on another person is said at the frame's number in the
    plate (1011 of a plate from 1001), as every other message names a plate's frames, not at
    its row (10)."""
    first, other, again = _dets(10), _dets(6, offset=1000.0), _dets(16)
    with caplog.at_level(logging.INFO, logger=video_detect.__name__):
        assert finish_split(first, _Child(other), 10, lambda f: again, first_frame=1001) is again
    assert "another face from frame 1011:" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger=video_detect.__name__):
        finish_split(first, _Child(other), 10, lambda f: again)       # a video: its rows
    assert "another face from frame 10:" in caplog.text


def test_a_plates_detection_numbers_from_its_first_file(tmp_path):
    for k in (1001, 1002, 1003):
        (tmp_path / f"sh.{k:04d}.png").write_bytes(b"")
    assert video_detect._first_number(str(tmp_path / "sh.%04d.png")) == 1001
    assert video_detect._first_number(tmp_path / "sh.####.png") == 1001
    assert video_detect._first_number(np.zeros((2, 4, 4, 3), np.uint8)) == 0
    assert video_detect._first_number("clip.mp4") == 0


@pytest.fixture(scope="module")
def one_process(data_dir):
    video = data_dir / "video" / "driving_d9.mp4"
    return video, detect_video(video, max_frames=N, workers=1)[0]


def _agree(split: ClipDetections, one: ClipDetections, m: int) -> None:
    """Frames before ``m`` exactly as one process's; from ``m`` on within MediaPipe's own
    warm-up differences (VideoLandmarker's notes: 0.05 px mean); no flow into frame ``m``."""
    assert split.n_frames == one.n_frames == N
    for name in ("points", "flow", "points478", "scores"):
        np.testing.assert_array_equal(getattr(split, name)[:m], getattr(one, name)[:m])
    d = np.linalg.norm(split.points[m:] - one.points[m:], axis=2)
    assert d.mean(axis=1).max() < 0.15 and d.max() < 0.5
    assert np.nanmax(np.abs(split.scores[m:] - one.scores[m:])) < 0.1     # tongueOut: NaN
    f = np.abs(split.flow[m + 1:] - one.flow[m + 1:])
    assert np.nanmean(f) < 0.05


def test_two_processes_agree_with_one(one_process, monkeypatch):
    video, one = one_process
    monkeypatch.setattr(video_detect, "SPLIT_MIN_FRAMES", 20)
    seen = []
    split = detect_video(video, max_frames=N, workers=2,
                         progress=lambda stage, d, t: seen.append(d))[0]
    m = N // 2
    _agree(split, one, m)
    assert np.isnan(split.flow[m]).all() and not np.isnan(one.flow[m]).all()
    assert max(seen) == N


def _broken_landmarker(fps, subject=None):
    raise RuntimeError("no landmarker here")


def test_a_failed_child_leaves_the_rest_to_this_process(one_process, monkeypatch, caplog):
    video, one = one_process
    monkeypatch.setattr(video_detect, "SPLIT_MIN_FRAMES", 20)

    monkeypatch.setattr(video_detect, "_child_landmarker", _broken_landmarker)  # in the child
    with caplog.at_level(logging.WARNING, logger="facetransfer.track.video_detect"):
        split = detect_video(video, max_frames=N, workers=2)[0]
    assert "the second detection process failed (RuntimeError: no landmarker here)" in caplog.text
    m = N // 2
    _agree(split, one, m)
    np.testing.assert_array_equal(split.flow[m], one.flow[m])   # resumed here: flow is exact


def test_an_interrupt_while_this_process_loads_its_landmarker_stops_the_child(
        data_dir, monkeypatch):
    """A Ctrl-C in the second or so MediaPipe takes to load this process's landmarker, after
    the child was forked: the child is cancelled (before, it was not: the interpreter's exit
    then waited for it to detect its half of the clip)."""
    children = []

    class _Started(_Child):
        @classmethod
        def start(cls, *args):
            children.append(cls(None))
            return children[-1]

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(video_detect, "SPLIT_MIN_FRAMES", 20)
    monkeypatch.setattr(video_detect, "SplitDetection", _Started)
    monkeypatch.setattr(video_detect, "FollowingLandmarker", interrupted)
    with pytest.raises(KeyboardInterrupt):
        detect_video(data_dir / "video" / "driving_d9.mp4", max_frames=N, workers=2)
    assert len(children) == 1 and children[0].cancelled


def test_the_child_takes_a_ctrl_c_inside_its_job_only(monkeypatch, capfd):
    """A Ctrl-C reaching the detection's child while it waited for its job, or (here) for the
    pool's end once its part was done, was raised in the pool's own loop: the child printed
    "Process ForkProcess-1: Traceback ... KeyboardInterrupt" under the CLI's line (1 of 48
    Ctrl-Cs into a 240-frame track). It is taken inside the job only."""
    import os
    import signal
    import time

    from facetransfer.track import detect

    monkeypatch.setattr(detect, "_import_mediapipe", lambda: None)
    monkeypatch.setattr(video_detect, "_detect_part", os.getpid)    # the child's part: its pid
    child = video_detect.SplitDetection.start("clip.mp4", 0, 1, 30.0)
    try:
        pid = child._future.result(timeout=30)
        os.kill(pid, signal.SIGINT)                 # as a terminal's Ctrl-C reaches it
        time.sleep(0.5)
    finally:
        child.cancel()
    assert pid != os.getpid() and "KeyboardInterrupt" not in capfd.readouterr().err


def test_the_child_reads_its_warm_up_and_part_as_a_whole_read(data_dir):
    """The child's frames past a keyframe (``driving_d6``: every 250 frames), reached by the
    container's seek: the frames of a read from the start, placeholders before the warm-up."""
    from facetransfer.io.video import read_video
    from facetransfer.io.video_display import exact_seek
    from facetransfer.track.detect import VideoLandmarker

    video = data_dir / "video" / "driving_d6.mp4"
    start, stop = 300, 306
    whole = read_video(video, max_frames=stop)[0]
    got = list(video_detect._child_frames(video, start, stop))
    warm = start - VideoLandmarker.warmup_frames
    assert exact_seek(video) and len(got) == stop and got[warm - 1] is None
    assert all(f is None for f in got[:warm])
    for a, b in zip(got[warm:], whole[warm:]):
        np.testing.assert_array_equal(a, b)
    arr = np.asarray(whole[:12])                   # an array's frames: all of them, as they are
    got = list(video_detect._child_frames(arr, 4, 10))
    assert len(got) == 10 and all(np.array_equal(a, b) for a, b in zip(got, arr))


def test_the_child_seeks_to_its_warm_up_instead_of_decoding_the_first_half(data_dir,
                                                                          monkeypatch):
    """The frames before the warm-up are not taken from the decoder one by one (the seek
    where it is exact; the test above passed with them decoded in turn, as before)."""
    from facetransfer.io import video_read
    from facetransfer.track.detect import VideoLandmarker

    calls = {"grab": 0, "read": 0}
    opened = video_read._open

    class Counted:
        def __init__(self, cap):
            self._cap = cap

        def __getattr__(self, name):
            if name in calls:
                calls[name] += 1
            return getattr(self._cap, name)

    monkeypatch.setattr(video_read, "_open", lambda path: Counted(opened(path)))
    start, stop = 300, 306
    got = list(video_detect._child_frames(data_dir / "video" / "driving_d6.mp4", start, stop))
    warm = start - VideoLandmarker.warmup_frames
    assert len(got) == stop and sum(f is not None for f in got) == stop - warm
    assert calls == {"grab": 0, "read": stop - warm}


def test_cli_rejects_workers_below_one(tmp_path, capsys, data_dir):
    code = main(["track", str(data_dir / "video" / "driving_d9.mp4"), "--out",
                 str(tmp_path / "t.npz"), "--workers", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == ["facetransfer track: error: --workers must be >= 1, got 0"]


def test_mediapipe_loads_without_its_drawing_helpers_until_they_are_used():
    """import_tasks_api makes MediaPipe's drawing helpers (matplotlib's pyplot) and its
    microphone module (which imports sounddevice) lazy; they still work when used, and a look
    at every loaded module (hypothesis scans sys.modules so) raises nothing: sounddevice
    itself lazy raised PortAudio's OSError there on a machine without it. PortAudio is not
    even searched for (before, the audio classifier's annotations loaded the microphone's
    module as the package imported: sounddevice tried and failed, unseen, on every start)."""
    import subprocess
    import sys

    code = ("import sys, ctypes.util\n"
            "looked = []\n"
            "find = ctypes.util.find_library\n"
            "ctypes.util.find_library = lambda name: looked.append(name) or find(name)\n"
            "from facetransfer.track.init import import_tasks_api\n"
            "BaseOptions, vision = import_tasks_api()\n"
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'\n"
            "assert not looked, f'searched for {looked}'\n"
            "assert vision.FaceLandmarkerOptions and BaseOptions\n"
            "spec = vision.drawing_utils.DrawingSpec(color=(1, 2, 3))\n"
            "assert spec.color == (1, 2, 3) and 'matplotlib.pyplot' in sys.modules\n"
            "assert vision.drawing_styles.get_default_face_mesh_contours_style()\n"
            "assert 'sounddevice' not in sys.modules\n"
            "[getattr(m, '__file__', None) for m in list(sys.modules.values())]\n"
            "print('ok')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]
