"""``batch track --occluders`` (and a clips manifest's ``occluders`` column): each clip's track
tested for a covered mouth or eye as ``track --occluders`` tests it, to the bit, the same note
in the summary; a chunked clip tested whole after its chunks are joined."""

from __future__ import annotations

import csv
import functools

import numpy as np
import pytest

from facetransfer.batch import cluster as batch_cluster
from facetransfer.cli.main import main
from facetransfer.track import Track

from _tracks import assert_same_track_file
from conftest import clip_with_points

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

#: A hand's colour over the rendered face (as tests/test_occlusion.py draws it).
HAND = (195, 140, 100)


@pytest.fixture
def inproc(monkeypatch):
    """The CLI's embedded cluster as worker threads of this process (fast, no network)."""
    orig = batch_cluster.open_client
    monkeypatch.setattr(batch_cluster, "open_client", functools.partial(orig, processes=False))


def _boxed_clip(model, n, seed, folder, name, covered=()):
    """An ``n``-frame synthetic clip ``folder/name.mp4`` and its first points, a hand-coloured
    box over the mouth (its true landmarks, 8 px beyond) in the frames ``covered``."""
    import cv2

    from facetransfer.io.video import write_video

    video, pts, clip = clip_with_points(model, n, seed, folder, video=f"{name}.mp4",
                                        points=f"{name}.json")
    if covered:
        frames = [f.copy() for f in clip.frames]
        for i in covered:
            lips = clip.truth.landmarks2d[i, 48:60]
            (x0, y0), (x1, y1) = (lips.min(0) - 8).astype(int), (lips.max(0) + 8).astype(int)
            cv2.rectangle(frames[i], (int(x0), int(y0)), (int(x1), int(y1)), HAND, -1)
        write_video(video, frames, 25)
    return video, pts


@pytest.fixture(scope="module")
def two_clips(quick_model, tmp_path_factory):
    """12-frame clips: ``a`` clean, ``b`` with its mouth covered in frames 4-8."""
    d = tmp_path_factory.mktemp("occlclips")
    return {"a": _boxed_clip(quick_model, 12, 3, d, "a"),
            "b": _boxed_clip(quick_model, 12, 4, d, "b", covered=range(4, 9))}


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _notes(path):
    with open(path, newline="") as fh:
        return {r["clip"]: (r["status"], r["note"]) for r in csv.DictReader(fh)}


def test_batch_track_occluders_is_track_occluders_per_clip(two_clips, quick_model_path, inproc,
                                                           tmp_path, capsys):
    """Two clips, one with a box over its mouth: ``batch track --occluders`` writes the track
    file ``track --occluders`` writes of each (its ``occluded`` to the bit) and the note it
    says, in the summary and on stderr; a rerun keeps both and says the notes again; the
    same batch without ``--occluders`` is another job (a failed row each, not "skipped")."""
    common = ("--model", quick_model_path, "--passes", "1")
    said = {}
    for name, (video, pts) in two_clips.items():
        code, out, err = _cli(capsys, "track", video, "--init", pts, "--out",
                              tmp_path / f"ref_{name}.npz", "--occluders", *common)
        assert code == 0, err
        said[name] = [ln[len("note: "):] for ln in out.splitlines()
                      if ln.startswith("note: ") and "covered" in ln][0]
    ref = {n: Track.load(tmp_path / f"ref_{n}.npz") for n in two_clips}
    assert not ref["a"].occluded.any()                      # the clean clip: nothing flagged
    mouth = np.flatnonzero(ref["b"].occluded[:, 0])
    assert set(range(4, 9)) <= set(mouth) and not ref["b"].occluded[:, 1:].any()
    assert said == {"a": "no mouth or eye found covered",
                    "b": f"covered: mouth in frames {mouth[0]}-{mouth[-1]} (recorded: the model "
                         "has no ARKit activations to bridge)"}
    man = tmp_path / "clips.csv"
    man.write_text("video,init\n" + "".join(f"{v},{p}\n" for v, p in two_clips.values()))
    out = tmp_path / "out"
    argv = ("batch", "track", "--manifest", man, "--out", out, "--workers", 2, *common)
    code, _, err = _cli(capsys, *argv, "--occluders")
    assert code == 0, err
    for name in two_clips:
        assert_same_track_file(out / f"{name}.npz", tmp_path / f"ref_{name}.npz")
    assert _notes(out / "summary.csv") == {n: ("done", said[n]) for n in said}
    assert f"b: note: {said['b']}" in err.splitlines()
    code, _, err = _cli(capsys, *argv, "--occluders")       # a rerun: skipped, still said
    assert code == 0 and _notes(out / "summary.csv") == {n: ("skipped", said[n]) for n in said}
    assert f"b: note: {said['b']}" in err.splitlines()
    code, _, err = _cli(capsys, *argv)                      # not the same job without it
    rows = _notes(out / "summary.csv")
    assert code == 1 and {s for s, _ in rows.values()} == {"failed"}, err


def test_a_manifests_occluders_column_asks_per_clip(two_clips, quick_model_path, inproc,
                                                    tmp_path, capsys):
    """``occluders`` yes/no per row, an empty cell taking ``--occluders``; a cell neither yes
    nor no is one line naming the manifest's line, exit 2, before anything runs; a track
    there of the other kind (no summary to say so) is a failed row, not kept as this job's."""
    (va, pa), (vb, pb) = two_clips["a"], two_clips["b"]
    common = ("--model", quick_model_path, "--passes", "1")
    man = tmp_path / "clips.csv"
    man.write_text(f"video,init,occluders\n{va},{pa},no\n{vb},{pb},\n")
    out = tmp_path / "out"
    code, _, err = _cli(capsys, "batch", "track", "--manifest", man, "--out", out,
                        "--occluders", *common)
    assert code == 0, err
    assert Track.load(out / "a.npz").occluded is None             # "no" wins over the flag
    assert Track.load(out / "b.npz").occluded[4:9, 0].all()       # empty: the flag's yes
    assert _cli(capsys, "track", va, "--init", pa, "--out", tmp_path / "ref_a.npz",
                *common)[0] == 0
    assert_same_track_file(out / "a.npz", tmp_path / "ref_a.npz")
    (out / "summary.csv").unlink()                   # the files alone say which kind they are
    man.write_text(f"video,init,occluders\n{va},{pa},YES\n{vb},{pb},0\n")
    code, _, err = _cli(capsys, "batch", "track", "--manifest", man, "--out", out, *common)
    rows = _notes(out / "summary.csv")
    assert code == 1 and {s for s, _ in rows.values()} == {"failed"}, err
    assert "holds a track not tested for occluders" in err
    assert "holds a track tested for occluders" in err
    man.write_text(f"video,init,occluders\n{va},{pa},maybe\n")
    code, _, err = _cli(capsys, "batch", "track", "--manifest", man, "--out", tmp_path / "o2",
                        *common)
    assert code == 2 and not (tmp_path / "o2").exists()
    assert err.strip().splitlines() == [
        f"facetransfer batch track: error: manifest {man} line 2: occluders must be yes or no "
        "(true/false, 1/0), got 'maybe'"], err


def test_a_chunked_clip_is_tested_whole_after_the_join(quick_model, quick_model_path, tmp_path,
                                                       capsys):
    """24 frames in chunks 0-13 and 10-23, the mouth covered in 15-22: 8 of the second
    chunk's 14 frames, which tested alone has the covered look as its median (the covered
    frames not found), 8 of the clip's 24. The joined track is tested whole, on a scheduler started apart: its
    ``occluded`` is the whole clip's test of its points, the covered frames found."""
    from dask.distributed import LocalCluster

    from facetransfer.io.video import read_video
    from facetransfer.track import occlusion as oc

    video, pts = _boxed_clip(quick_model, 24, 7, tmp_path, "long", covered=range(15, 23))
    out = tmp_path / "out"
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as running:
        code, _, err = _cli(capsys, "batch", "track", video, "--init", pts, "--out", out,
                            "--chunk", 14, "--overlap", 4, "--occluders", "--model",
                            quick_model_path, "--passes", "1", "--scheduler",
                            running.scheduler_address)
    assert code == 0, err
    joined = Track.load(out / "long.npz")
    frames, _ = read_video(video)
    whole = oc.clip_occlusion(frames, oc.track_points(joined))
    assert np.array_equal(joined.occluded, whole.occluded)
    assert set(range(15, 23)) <= set(np.flatnonzero(joined.occluded[:, 0]))
    # what the second chunk's own test would say: its covered frames not found (its clean
    # ones taken for covered instead)
    alone = oc.clip_occlusion(frames[10:], oc.track_points(joined)[10:])
    assert not alone.occluded[15 - 10:23 - 10, 0].all() and alone.occluded[:15 - 10, 0].any()
    assert _notes(out / "summary.csv")["long"][1].startswith("covered: mouth in frames ")
