"""``facetransfer batch transfer --matte png|tiff|exr`` on an in-process Dask LocalCluster: each
pair's matte beside its result (``DIR/NAME.matte/NAME.%05d.png``), the matte ``transfer
--matte`` writes; the summary's ``matte`` column; reruns that skip what is whole and redo a
pair whose matte is not there (added by the rerun, or deleted)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.io.video import read_video  # noqa: E402

import test_batch  # noqa: E402

# the batch tests' synthetic clips, in-process cluster and helpers, shared
clips, inproc = test_batch.clips, test_batch.inproc
_cli, _summary = test_batch._cli, test_batch._summary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def pairs(clips, quick_model_path, tmp_path_factory):
    """A pairs manifest of two pairs (a's target with b's expressions, b's with a's), tracked
    once."""
    from facetransfer.cli.main import main

    d = tmp_path_factory.mktemp("mattepairs")
    tracks = {}
    for n in "ab":
        v, p, _ = clips[n]
        tracks[n] = d / f"{n}.npz"
        assert main([str(a) for a in ("track", v, "--model", quick_model_path, "--out",
                                      tracks[n], "--init", p, "--passes", "1",
                                      "--no-progress")]) == 0
    man = d / "pairs.csv"
    man.write_text("name,target,target_track,expression_from,source_track\n"
                   + "".join(f"{t}{s},{clips[t][0]},{tracks[t]},{clips[s][0]},{tracks[s]}\n"
                             for t, s in ("ab", "ba")))
    return man, tracks


def _pngs(folder: Path) -> dict[str, np.ndarray]:
    return {f.name: cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in sorted(folder.iterdir())}


def _stamps(folder: Path) -> dict[str, int]:
    return {f.name: f.stat().st_mtime_ns for f in folder.iterdir()}


def test_batch_mattes_are_transfer_s_and_reruns_do_only_what_lacks_one(
        pairs, clips, quick_model_path, inproc, tmp_path, capsys):
    """A batch run without ``--matte``, then with it: both pairs are done again (their results
    were kept, their mattes were not there) and each writes the matte ``transfer --matte``
    writes, bit for bit, 16-bit, one frame per result frame numbered from 0, 0 far from the
    face; the summary names it. The same command again skips both, touching nothing; after
    one matte folder is deleted, that pair alone is done again, its matte as it was."""
    man, tracks = pairs
    out = tmp_path / "out"

    def batch(*more):
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", "--crf", "0", *more)

    code, said, err = batch()
    assert code == 0 and "(2 done)" in said, (said, err)
    assert {n: r["matte"] for n, r in _summary(out / "summary.csv").items()} == \
        {"ab": "", "ba": ""}
    assert sorted(p.name for p in out.iterdir()) == ["ab.mp4", "ba.mp4", "summary.csv"]
    code, said, err = batch("--matte", "png")
    assert code == 0 and "(2 done)" in said, (said, err)
    rows = _summary(out / "summary.csv")
    for n in ("ab", "ba"):
        assert rows[n]["status"] == "done"
        assert rows[n]["matte"] == str(out / f"{n}.matte" / f"{n}.%05d.png")
    mattes = {n: _pngs(out / f"{n}.matte") for n in ("ab", "ba")}
    for n, m in mattes.items():
        assert list(m) == [f"{n}.{i:05d}.png" for i in range(8)]
        result, _ = read_video(out / f"{n}.mp4")
        for frame in m.values():
            assert frame.dtype == np.uint16 and frame.shape == result.shape[1:3]
            assert frame.max() == 65535 and frame[:8, :8].max() == 0 == frame[-8:, -8:].max()

    # the matte `transfer --matte` writes for pair ab, with a lossless output: the invariant
    ref = tmp_path / "ref"
    (ref / "out").mkdir(parents=True)
    code, _, err = _cli(capsys, "transfer", "--target", clips["a"][0], "--target-track",
                        tracks["a"], "--expression-from", clips["b"][0], "--source-track",
                        tracks["b"], "--model", quick_model_path, "--no-progress", "--out",
                        ref / "out" / "%05d.png", "--matte", ref / "matte" / "%05d.png")
    assert code == 0, err
    plate, _ = read_video(clips["a"][0])
    want = list(_pngs(ref / "matte").values())
    for image, p, m in zip(_pngs(ref / "out").values(), plate, want):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        changed = np.any(image != p, axis=-1)
        assert changed.any() and not (changed & (m == 0)).any()
        np.testing.assert_array_equal(image[m == 0], p[m == 0])
    assert len(want) == 8
    for got, m in zip(mattes["ab"].values(), want):
        np.testing.assert_array_equal(got, m)

    before = {n: _stamps(out / f"{n}.matte") for n in ("ab", "ba")}
    results = {n: (out / f"{n}.mp4").stat().st_mtime_ns for n in ("ab", "ba")}
    code, said, err = batch("--matte", "png")
    assert code == 0 and "(2 skipped)" in said, (said, err)
    assert {n: _stamps(out / f"{n}.matte") for n in ("ab", "ba")} == before
    assert {n: (out / f"{n}.mp4").stat().st_mtime_ns for n in ("ab", "ba")} == results
    assert {n: r["matte"] for n, r in _summary(out / "summary.csv").items()} == \
        {n: str(out / f"{n}.matte" / f"{n}.%05d.png") for n in ("ab", "ba")}

    import shutil

    shutil.rmtree(out / "ba.matte")
    code, said, err = batch("--matte", "png")
    assert code == 0 and "(1 done, 1 skipped)" in said, (said, err)
    rows = _summary(out / "summary.csv")
    assert (rows["ab"]["status"], rows["ba"]["status"]) == ("skipped", "done")
    assert _stamps(out / "ab.matte") == before["ab"]
    again = _pngs(out / "ba.matte")
    assert list(again) == list(mattes["ba"])
    for name, m in again.items():
        np.testing.assert_array_equal(m, mattes["ba"][name])

    (out / "ab.matte" / "ab.00007.png").unlink()          # a matte short of a frame
    code, said, err = batch("--matte", "png")
    assert code == 0 and "(1 done, 1 skipped)" in said, (said, err)
    assert _summary(out / "summary.csv")["ab"]["status"] == "done"
    assert list(_pngs(out / "ab.matte")) == list(mattes["ab"])
    # a run without --matte skips both, and its summary still names the mattes they have
    code, said, err = batch()
    assert code == 0 and "(2 skipped)" in said, (said, err)
    assert {n: r["matte"] for n, r in _summary(out / "summary.csv").items()} == \
        {n: str(out / f"{n}.matte" / f"{n}.%05d.png") for n in ("ab", "ba")}


def test_a_video_matte_is_refused_before_any_work(pairs, quick_model_path, tmp_path, capsys):
    """``--matte mov`` (a video, not a sequence): one line, exit 2, no output folder."""
    man, _ = pairs
    with pytest.raises(SystemExit) as e:                 # the parser's error
        _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
             "--out", tmp_path / "out", "--matte", "mov")
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("facetransfer")]
    assert e.value.code == 2 and len(err) == 1, err
    assert "--matte: expected png, tiff, exr (an image sequence; `transfer --matte M.mov` " \
        "writes a lossless video matte of one transfer), got 'mov'" in err[0]
    assert not (tmp_path / "out").exists()


def test_each_job_s_matte_has_a_folder_of_its_own():
    """The layout: beside the result, named as the job, one folder per job, holding that job's
    frames only: no file of one job's matte nor a result lies in another job's matte folder,
    even of names made to collide (``a`` beside ``a.matte``, ``a.00000``). (Before, the last
    check compared ``D/a.matte`` with ``D/a.matte.matte``, which no layout could fail.)"""
    from facetransfer.batch.run import MATTE_FORMATS, matte_pattern

    assert matte_pattern(Path("D"), "sh010", ".png") == Path("D/sh010.matte/sh010.%05d.png")
    assert [matte_pattern("D", "a", s).name for s in MATTE_FORMATS.values()] == \
        ["a.%05d.png", "a.%05d.tif", "a.%05d.exr"]
    names = ["a", "a.matte", "a.00000", "a.matte.matte", "b"]
    folders = {n: matte_pattern("D", n, ".png").parent for n in names}
    assert len(set(folders.values())) == len(names)
    frames = {n: {Path(str(matte_pattern("D", n, s)) % i) for s in MATTE_FORMATS.values()
                  for i in (0, 1, 1001)} for n in names}
    results = {n: {Path("D") / f"{n}{e}" for e in (".mp4", ".mov")} for n in names}
    for n in names:
        assert all(f.parent == folders[n] for f in frames[n])
        for other in names:
            if other != n:
                assert not any(f.is_relative_to(folders[n])
                               for f in frames[other] | results[other]), (n, other)


@pytest.mark.parametrize("matte, name, said", [
    ("mov", "a", "--matte must be one of png, tiff, exr (an image sequence), got 'mov'"),
    ("png", "sh%03", "'sh%03' cannot name the frames of its matte"),
    ("exr", "take#2", "'take#2' cannot name the frames of its matte")])
def test_the_library_refuses_a_bad_matte_before_any_folder(matte, name, said, tmp_path):
    from facetransfer.batch import BatchError, PairJob, batch_transfer

    job = PairJob(name=name, target=tmp_path / "t.mp4", sources={})
    with pytest.raises(BatchError, match=re.escape(said)):
        batch_transfer([job], tmp_path / "out", None, client=None, settings={}, matte=matte)
    assert not (tmp_path / "out").exists()


def test_a_pair_stopped_mid_render_continues_its_result_and_its_matte(
        pairs, quick_model_path, inproc, tmp_path, capsys, monkeypatch):
    """A pair whose render failed at frame 4 (a worker's error: the render cache keeps what
    was written) is continued by the rerun from frame 4, result and matte, both whole."""
    import facetransfer.rewrite_clip as rc
    from facetransfer.io import video_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(video_parts, "PART_FRAMES", 2)
    real, calls, stop = rc._ClipRenderer.__call__, [], [4]

    def counted(self, i):
        if stop[0] is not None and i >= stop[0]:
            raise RuntimeError("the worker stopped")
        calls.append(i)
        return real(self, i)

    monkeypatch.setattr(rc._ClipRenderer, "__call__", counted)
    man = tmp_path / "one.csv"
    man.write_text("".join(pairs[0].read_text().splitlines(keepends=True)[:2]))   # ab
    out = tmp_path / "out"
    argv = ("batch", "transfer", "--manifest", man, "--model", quick_model_path, "--out", out,
            "--workers", "1", "--no-progress", "--matte", "tiff")
    code, said, _ = _cli(capsys, *argv)
    assert code == 1 and "(1 failed)" in said and sorted(calls) == [0, 1, 2, 3]
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]
    stop[0], calls[:] = None, []
    code, said, err = _cli(capsys, *argv)
    assert code == 0 and "(1 done)" in said, (said, err)
    assert sorted(calls) == [4, 5, 6, 7]
    assert len(read_video(out / "ab.mp4")[0]) == 8
    tifs = sorted((out / "ab.matte").iterdir())
    assert [p.name for p in tifs] == [f"ab.{i:05d}.tif" for i in range(8)]
    assert all(cv2.imread(str(p), cv2.IMREAD_UNCHANGED).dtype == np.uint16 for p in tifs)
    assert _summary(out / "summary.csv")["ab"]["matte"] == str(out / "ab.matte" / "ab.%05d.tif")


def test_a_pair_done_again_leaves_no_other_matte_in_its_folder(
        pairs, quick_model_path, inproc, tmp_path, capsys):
    """``NAME.matte/`` holds the matte of ``NAME``'s result and nothing else: a rerun in
    another format removes the earlier format's frames (a compositor pointing a reader at
    the folder would otherwise find two sequences, ``ab.00000.png`` beside ``ab.00000.exr``),
    and a pair done again without ``--matte`` (``--overwrite``) removes the matte it no
    longer made, which its row does not name."""
    man = tmp_path / "one.csv"
    man.write_text("".join(pairs[0].read_text().splitlines(keepends=True)[:2]))   # ab
    out = tmp_path / "out"

    def batch(*more):
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", *more)

    code, said, err = batch("--matte", "png")
    assert code == 0 and "(1 done)" in said, (said, err)
    code, said, err = batch("--matte", "exr")
    assert code == 0 and "(1 done)" in said, (said, err)
    assert sorted(p.name for p in (out / "ab.matte").iterdir()) == \
        [f"ab.{i:05d}.exr" for i in range(8)]
    assert _summary(out / "summary.csv")["ab"]["matte"] == str(out / "ab.matte" / "ab.%05d.exr")
    (out / "ab.matte" / "notes.txt").write_text("mine")      # not a matte's frame: kept
    code, said, err = batch("--overwrite")
    assert code == 0 and "(1 done)" in said, (said, err)
    assert _summary(out / "summary.csv")["ab"]["matte"] == ""
    assert sorted(p.name for p in (out / "ab.matte").iterdir()) == ["notes.txt"]


def test_a_plate_targets_matte_is_numbered_as_the_plate_and_kept(pairs, clips, quick_model_path,
                                                                 inproc, tmp_path, capsys,
                                                                 monkeypatch):
    """A pair whose target is a PNG plate numbered from 1001: its matte's frames are numbered
    from 1001 as ``transfer --matte`` numbers them (``--help`` and README say so; nothing
    tested it), and the rerun finds that matte whole and skips the pair (a check of whole
    mattes counted from 0 would redo it every run)."""
    from test_video_sequence import _plate

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    _, tracks = pairs
    _plate(tmp_path / "plate", read_video(clips["a"][0])[0])
    man = tmp_path / "plate.csv"
    man.write_text("name,target,target_track,expression_from,source_track\n"
                   f"sh010,plate/sh010.####.png,{tracks['a']},{clips['b'][0]},{tracks['b']}\n")
    out = tmp_path / "out"
    argv = ("batch", "transfer", "--manifest", man, "--model", quick_model_path, "--out", out,
            "--workers", "1", "--no-progress", "--matte", "png")
    code, said, err = _cli(capsys, *argv)
    assert code == 0 and "(1 done)" in said, (said, err)
    assert sorted(p.name for p in (out / "sh010.matte").iterdir()) == \
        [f"sh010.{1001 + i:05d}.png" for i in range(8)]
    before = _stamps(out / "sh010.matte")
    code, said, err = _cli(capsys, *argv)
    assert code == 0 and "(1 skipped)" in said, (said, err)
    assert _stamps(out / "sh010.matte") == before
    assert _summary(out / "summary.csv")["sh010"]["matte"] == \
        str(out / "sh010.matte" / "sh010.%05d.png")


def test_a_summary_written_before_the_options_left_their_defaults_out_keeps_its_results(
        pairs, quick_model_path, inproc, tmp_path, capsys, monkeypatch):
    """A ``batch transfer`` summary whose digests hold every setting's ``repr`` (the version
    before :func:`facetransfer.batch.run.transfer_what`): the same command now skips both
    pairs, their results untouched, and records the digests of the words now; a changed
    option still refuses them (a failed row, the result kept)."""
    from facetransfer.batch import run as batch_run

    man, _ = pairs
    out = tmp_path / "out"

    def batch(*more):
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", *more)

    now = batch_run.transfer_what
    monkeypatch.setattr(batch_run, "transfer_what", batch_run._transfer_what_before)
    code, said, err = batch()
    assert code == 0 and "(2 done)" in said, (said, err)
    old = {n: r["job"] for n, r in _summary(out / "summary.csv").items()}
    made = {n: (out / f"{n}.mp4").stat().st_mtime_ns for n in ("ab", "ba")}
    monkeypatch.setattr(batch_run, "transfer_what", now)
    code, said, err = batch()
    assert code == 0 and "(2 skipped)" in said, (said, err)
    rows = _summary(out / "summary.csv")
    assert all(rows[n]["job"].startswith("v2:") and rows[n]["job"] != old[n] for n in made)
    assert {n: (out / f"{n}.mp4").stat().st_mtime_ns for n in made} == made
    code, said, err = batch("--blend", "none")
    assert code == 1 and "(2 failed)" in said, (said, err)
    assert {n: (out / f"{n}.mp4").stat().st_mtime_ns for n in made} == made


def test_a_matte_beside_no_result_is_rendered_again_without_overwrite(
        pairs, quick_model_path, inproc, tmp_path, capsys):
    """A pair's matte whose result is not there (a render stopped between the two commits, the
    matte's first; or the result removed to redo the pair alone, as a failed row says) is the
    run's own: the rerun renders the pair, result and matte, without ``--overwrite`` (before,
    the render refused the frames, "pass --overwrite", and the pair failed at every rerun)."""
    man = tmp_path / "one.csv"
    man.write_text("".join(pairs[0].read_text().splitlines(keepends=True)[:2]))   # ab
    out = tmp_path / "out"

    def batch():
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", "--matte", "png")

    code, said, err = batch()
    assert code == 0 and "(1 done)" in said, (said, err)
    first = _pngs(out / "ab.matte")
    (out / "ab.mp4").unlink()
    code, said, err = batch()
    row = _summary(out / "summary.csv")["ab"]
    assert code == 0 and "(1 done)" in said, (said, err, row["error"])
    assert len(read_video(out / "ab.mp4")[0]) == 8
    again = _pngs(out / "ab.matte")
    assert sorted(again) == sorted(first) == [f"ab.{i:05d}.png" for i in range(8)]
    assert all(np.array_equal(first[k], again[k]) for k in first)
    assert row["matte"] == str(out / "ab.matte" / "ab.%05d.png")
