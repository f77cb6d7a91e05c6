"""``batch export`` of one set of tracks in two formats into one folder (a take for Unreal, a glb
for Blender): each run's outputs kept, each rerun skipping its own (batchfmt55)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import test_batch  # noqa: E402
import test_batch_matte  # noqa: E402

clips, inproc, pairs = test_batch.clips, test_batch.inproc, test_batch_matte.pairs
_cli, _summary = test_batch._cli, test_batch._summary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _rows(path) -> dict:
    """``{(clip, output file name): row}`` of a summary (a clip has a row per output)."""
    import csv

    with open(path, newline="", encoding="utf-8") as fh:
        return {(r["clip"], Path(r["output"]).name): r for r in csv.DictReader(fh)}


def test_two_formats_into_one_folder_each_rerun_skips_its_own(
        arkit_model, arkit_model_path, make_arkit_track, inproc, tmp_path, capsys):
    """Takes, then glbs, into one folder: before, the glb run's rows replaced the takes' in
    the summary, and the takes' rerun refused every take ("made from other inputs or
    options", the glb job's digest); now the summary holds a row per output, and each
    format's rerun skips its two, with their figures, the other's rows kept."""
    tracks = [make_arkit_track(arkit_model, frames, seed=n, fps=fps)[0].save(
        tmp_path / f"t{n}.npz") for n, (frames, fps) in enumerate(((9, 25.0), (6, 30.0)))]
    out = tmp_path / "out"

    def export(fmt):
        return _cli(capsys, "batch", "export", *tracks, "--format", fmt, "--out", out,
                    "--model", arkit_model_path, "--workers", "1", "--no-progress")

    for fmt in ("livelink", "glb"):
        assert export(fmt)[0] == 0
    made = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.name != "summary.csv"}
    assert sorted(made) == ["t0.csv", "t0.glb", "t1.csv", "t1.glb"], made
    first = _rows(out / "summary.csv")
    assert sorted(first) == [("t0", "t0.csv"), ("t0", "t0.glb"), ("t1", "t1.csv"),
                             ("t1", "t1.glb")], first
    for fmt, ext in (("livelink", ".csv"), ("glb", ".glb"), ("livelink", ".csv")):
        before = _rows(out / "summary.csv")
        code, said, err = export(fmt)
        assert code == 0 and "(2 skipped)" in said, (fmt, said, err)
        rows = _rows(out / "summary.csv")
        # this format's rows skipped, with the digest and figures of the run that made them;
        # the other format's rows as they were
        assert {k: (r["status"], r["job"], r["frames"], r["fps"]) for k, r in rows.items()} == \
            {k: ("skipped" if k[1].endswith(ext) else before[k]["status"], r["job"],
                 r["frames"], r["fps"]) for k, r in first.items()}, rows
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()
            if p.name != "summary.csv"} == made                      # none written again


def test_two_codecs_into_one_folder_keep_each_result_and_the_matte(
        pairs, quick_model_path, inproc, tmp_path, capsys):
    """``batch transfer --matte png`` (H.264, ``NAME.mp4`` and ``NAME.matte/``), then the same
    pairs as ProRes (``NAME.mov``) into the same folder: before, the ProRes run removed the
    H.264 results' mattes (a render without ``--matte`` clears its pair's matte folder) and
    its rows replaced theirs, so the first command again rendered both pairs anew; now each
    command again skips its two, the mattes untouched. A ProRes run asking for a matte there
    is refused (the folder is the H.264 result's), pair by pair, in one line."""
    man, _ = pairs
    out = tmp_path / "out"

    def batch(*more):
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", "--max-frames", "4", *more)

    assert batch("--matte", "png")[0] == 0
    mattes = {f.relative_to(out): f.stat().st_mtime_ns for f in out.glob("*.matte/*")}
    assert len(mattes) == 8, mattes
    assert batch("--codec", "prores")[0] == 0
    assert sorted(p.name for p in out.glob("*.m[op4v]*")) == ["ab.mov", "ab.mp4", "ba.mov",
                                                               "ba.mp4"]
    for more in (("--matte", "png"), ("--codec", "prores"), ("--matte", "png")):
        code, said, err = batch(*more)
        assert code == 0 and "(2 skipped)" in said, (more, said, err)
        assert {f.relative_to(out): f.stat().st_mtime_ns for f in out.glob("*.matte/*")} == \
            mattes
    code, said, err = batch("--codec", "prores", "--matte", "png")
    assert code == 1 and "2 failed" in said, (said, err)
    rows = _rows(out / "summary.csv")
    assert {k for k, r in rows.items() if r["status"] == "failed"} == {("ab", "ab.mov"),
                                                                       ("ba", "ba.mov")}
    assert all(f"{k[0]}.mp4" in r["error"] and "\n" not in r["error"]
               for k, r in rows.items() if r["status"] == "failed"), rows
    assert {f.relative_to(out): f.stat().st_mtime_ns for f in out.glob("*.matte/*")} == mattes


def test_a_matte_beside_another_codecs_result_is_refused_only_where_that_result_has_one(
        tmp_path):
    """A ProRes run with ``--matte`` beside an H.264 result of the same pair: refused where
    ``NAME.matte/`` holds that result's frames, free where the H.264 run wrote no matte (the
    folder absent or empty; before, refused too, naming a matte that did not exist)."""
    from types import SimpleNamespace

    from facetransfer.batch.run import _mattes_of_other_results

    (tmp_path / "ab.mp4").write_bytes(b"h264")
    jobs, outs = [SimpleNamespace(name="ab")], {"ab": tmp_path / "ab.mov"}
    mattes = {"ab": tmp_path / "ab.matte" / "ab.%05d.png"}
    assert _mattes_of_other_results(jobs, outs, mattes, {}) == {}
    (tmp_path / "ab.matte").mkdir()
    assert _mattes_of_other_results(jobs, outs, mattes, {}) == {}
    (tmp_path / "ab.matte" / "ab.00000.png").write_bytes(b"png")
    rows = _mattes_of_other_results(jobs, outs, mattes, {})
    assert rows["ab"].status == "failed" and "ab.mp4" in rows["ab"].error
    assert _mattes_of_other_results(jobs, outs, mattes, {"ab": rows["ab"]}) == {}
