"""A transfer's saved new performance (``transfer --save-track``) is marked as one
(:attr:`facetransfer.track.Track.made_by`) and refused as a clip's track (``--target-track``,
``--source-track``, ...), in one line naming the file and the option; it still drives what a
performance drives (``--performance``, ``puppet``, ``edit``); a track file without
the mark is a clip's track as before (fifty-sixth session)."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from facetransfer.errors import RewriteError, TrackError  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.video import read_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.project import take_frames  # noqa: E402
from facetransfer.track.result import MADE_BY_TRANSFER, made_by_of  # noqa: E402
import test_transfer_cli  # noqa: E402

clips = test_transfer_cli.clips          # its fixture: the synthetic target and source clips


def run(argv, capsys):
    code = main([str(a) for a in argv])
    said = capsys.readouterr()
    return code, said.out, said.err


@pytest.fixture(scope="module")
def saved(clips, quick_model_path, tmp_path_factory):
    """A transfer of the clips' source expressions onto their target, its new performance
    saved (``--save-track``): ``(performance path, result path)``."""
    d = tmp_path_factory.mktemp("saved")
    perf, out = d / "new.npz", d / "first.mp4"
    code = main([str(a) for a in (
        "transfer", "--target", clips["target"], "--target-track", clips["target_track"],
        "--expression-from", clips["source"], "--source-track", clips["source_track"],
        "--model", quick_model_path, "--save-track", perf, "--out", out, "--no-progress")])
    assert code == 0
    return perf, out


def _transfer(clips, model, out, **tracks):
    """``transfer`` argv of the clips with the given track files (``target_track=...``)."""
    argv = ["transfer", "--target", clips["target"], "--expression-from", clips["source"],
            "--model", model, "--out", out, "--no-progress"]
    for key, flag in (("target_track", "--target-track"), ("source_track", "--source-track")):
        argv += [flag, tracks.get(key, clips[key])]
    for key, flag, video in (("identity_track", "--identity-track", "--identity-from"),
                             ("pose_track", "--pose-track", "--pose-from")):
        if key in tracks:
            argv += [video, clips["source"], flag, tracks[key]]
    return argv


def test_the_saved_performance_is_marked_and_a_clips_track_is_not(saved, clips):
    perf, _ = saved
    with np.load(perf) as z:
        assert str(z["made_by"]) == MADE_BY_TRANSFER == "transfer"
    with np.load(clips["target_track"]) as z:
        assert "made_by" not in z.files          # a clip's track: written as before
    assert Track.load(perf).made_by == "transfer"
    assert Track.load(clips["target_track"]).made_by == ""
    assert made_by_of(perf) == "transfer" and made_by_of(clips["target_track"]) == ""


@pytest.mark.parametrize("key,flag", [("target_track", "--target-track"),
                                      ("source_track", "--source-track"),
                                      ("identity_track", "--identity-track"),
                                      ("pose_track", "--pose-track")])
def test_a_saved_performance_as_a_clips_track_is_one_line(saved, clips, quick_model_path,
                                                         tmp_path, capsys, key, flag):
    """Before: exit 0, the performance's expressions taken for the clip's (a 512² target's
    mouths measured 0.006 open instead of 0.108)."""
    perf, _ = saved
    out = tmp_path / "second.mp4"
    code, _, err = run(_transfer(clips, quick_model_path, out, **{key: perf}), capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"{flag} {perf} is a transfer's saved performance" in lines[0], err
    assert "facetransfer track" in lines[0] and f"leave {flag} out" in lines[0], err
    assert "--performance" in lines[0]
    assert not out.exists()


def test_a_track_without_the_mark_is_a_clips_track_as_before(clips, quick_model_path,
                                                             tmp_path, capsys):
    """An older file (no ``made_by`` key) is read as a track: the transfer runs as with the
    clip's track it is."""
    old = tmp_path / "old.npz"
    with np.load(clips["target_track"]) as z:
        np.savez(old, **{k: z[k] for k in z.files})
    out = tmp_path / "old.mp4"
    code, _, err = run(_transfer(clips, quick_model_path, out, target_track=old), capsys)
    assert code == 0, err
    assert len(read_video(out)[0]) == 6


def test_the_saved_performance_still_drives(saved, clips, quick_model_path, tmp_path,
                                            capsys):
    """As ``--performance`` it renders on its target (all six frames, the mouth changed where
    the source opened it); ``puppet`` and ``edit`` take it; an edit keeps the mark. (``view``
    and ``export`` read it with :meth:`Track.load` as any track: their ARKit timelines need
    the default model, run by hand on the real clips, BENCHMARKS.md.)"""
    perf, first = saved
    out = tmp_path / "perf.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--performance", perf, "--model",
                        quick_model_path, "--out", out, "--no-progress"], capsys)
    assert code == 0, err
    frames, target = read_video(out)[0], read_video(clips["target"])[0]
    assert frames.shape == target.shape
    d = np.abs(frames[1].astype(int) - target[1].astype(int)).max(axis=-1)
    assert d[40:100, 40:90].max() > 40         # frame 1: the source's open mouth
    code, _, err = run(["puppet", perf, "--model", quick_model_path, "--identity", "id04",
                        "--out", tmp_path / "puppet.mp4"], capsys)
    assert code == 0, err
    assert len(read_video(tmp_path / "puppet.mp4")[0]) == 6
    edited = tmp_path / "edited.npz"
    code, _, err = run(["edit", perf, "--model", quick_model_path, "--scale", "smile=1.5",
                        "--out", edited], capsys)
    assert code == 0, err
    assert Track.load(edited).made_by == "transfer"


def test_the_library_refuses_it_before_any_work(saved, clips, quick_model):
    """:func:`facetransfer.transfer_plan.plan_transfer` (batch transfer jobs too): the refusal
    names the file and the option; a missing target video is not read first."""
    from facetransfer.transfer_plan import plan_transfer

    perf, _ = saved
    with pytest.raises(RewriteError, match="--target-track .*new.npz is a transfer's saved"):
        plan_transfer("no/such/target.mp4", quick_model, target_track=perf,
                      expression_from=clips["source"])


def test_the_mark_is_kept_by_the_transforms_and_checked(saved, tmp_path):
    perf, _ = saved
    t = Track.load(perf)
    one = take_frames(t, np.array([2]))
    assert one.made_by == "transfer"
    one.save(tmp_path / "one.npz")
    assert made_by_of(tmp_path / "one.npz") == "transfer"
    with pytest.raises(TrackError, match="made_by must be a line"):
        dataclasses.replace(t, made_by="two\nlines")
    bad = tmp_path / "bad.npz"
    with np.load(perf) as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(bad, **{**arrays, "made_by": np.float64(1.0)})
    with pytest.raises(TrackError, match=r"'made_by' must hold text"):
        Track.load(bad)
    assert made_by_of(bad) == "" and made_by_of(tmp_path / "missing.npz") == ""
    np.save(tmp_path / "array.npy", np.zeros(3))            # an .npy, or one named .npz
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")
    assert made_by_of(tmp_path / "array.npz") == ""


def test_the_mark_is_no_part_of_a_renders_key(saved):
    """The mark changes no pixel: a render's key digests the track without it (the cached
    renders of the transfers made before it are still found)."""
    import hashlib

    from facetransfer.render_cache import _update_track

    t = Track.load(saved[0])
    keys = []
    for made in ("", "transfer"):
        h = hashlib.sha256()
        _update_track(h, dataclasses.replace(t, made_by=made))
        keys.append(h.hexdigest())
    assert keys[0] == keys[1]


def test_a_batch_manifest_with_a_saved_performance_as_a_track_is_refused(saved, clips,
                                                                        tmp_path):
    """``batch transfer``: the manifest is refused before any job runs, naming its line, the
    column and the file; the same row with the clip's track is a job."""
    from facetransfer.batch.manifest import BatchError, pair_jobs

    perf, _ = saved
    manifest = tmp_path / "pairs.csv"
    for track, refused in ((perf, True), (clips["target_track"], False)):
        manifest.write_text("target,expression_from,target_track\n"
                            f"{clips['target']},{clips['source']},{track}\n")
        if refused:
            with pytest.raises(BatchError) as info:
                pair_jobs(manifest)
            line = str(info.value)
            assert line.startswith(f"manifest {manifest} line 2: target_track ") and \
                "is a transfer's saved performance" in line and "leave target_track out" \
                in line and "give it as performance" in line and "\n" not in line, line
        else:
            assert len(pair_jobs(manifest)) == 1
