"""Batch manifests and the summary table (:mod:`facetransfer.batch.manifest`, ``.summary``)."""

from __future__ import annotations

import pytest

from facetransfer.batch import (BatchError, Row, clip_jobs, export_jobs, pair_jobs, read_summary,
                                write_summary)


def test_clip_manifest_resolves_paths_against_its_folder(tmp_path):
    d = tmp_path / "m"
    d.mkdir()
    man = d / "clips.csv"
    man.write_text("video,name,init\n"
                   "takes/one.mp4,,pts/one.json\n"
                   "\n"
                   f"{tmp_path / 'two.mp4'},second,\n")
    jobs = clip_jobs(["/data/three.mp4"], man)
    assert [(j.name, j.video, j.init) for j in jobs] == [
        ("three", "/data/three.mp4", "auto"),
        ("one", str(d / "takes" / "one.mp4"), str(d / "pts" / "one.json")),
        ("second", str(tmp_path / "two.mp4"), "auto")]


@pytest.mark.parametrize("text, message", [
    ("", "is empty"),
    ("video,fps\nx.mp4,25\n", "unknown column(s) ['fps']"),
    ("name\nx\n", "lacks the column(s) ['video']"),
    ("video,name\n,x\n", "line 2: column 'video' is empty"),
    ("video\n", "has no rows"),
    ("video,name\nx.mp4,../up\n", "'../up' cannot be an output file name"),
])
def test_bad_clip_manifests(tmp_path, text, message):
    man = tmp_path / "bad.csv"
    man.write_text(text)
    with pytest.raises(BatchError) as e:
        clip_jobs(manifest=man)
    assert message in str(e.value) and "bad.csv" in str(e.value)


def test_the_face_to_track_per_clip_and_per_pair(tmp_path):
    """``face`` (clips) and ``target_face`` / ``source_face`` (pairs) are values, not paths; an
    empty cell takes ``--face``; a cell that names no place fails before any clip runs."""
    man = tmp_path / "clips.csv"
    man.write_text('video,face\na.mp4,right\nb.mp4,\nc.mp4,"120, 80"\n')
    jobs = clip_jobs(["d.mp4"], man, face="left")
    assert [(j.name, j.face) for j in jobs] == [("d", "left"), ("a", "right"), ("b", "left"),
                                                ("c", "120, 80")]
    assert clip_jobs(["d.mp4"])[0].face is None
    with pytest.raises(BatchError, match="--face must be left, right, centre or pixels X,Y, "
                                         "got 'upstairs'"):
        clip_jobs(["d.mp4"], face="upstairs")
    man.write_text("video,face\na.mp4,right\nb.mp4,middle\n")
    with pytest.raises(BatchError, match=r"clips.csv row 2: face must be left, right, centre "
                                         r"or pixels X,Y, got 'middle'"):
        clip_jobs(manifest=man)
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("target,expression_from,target_face,source_face\nt.mp4,s.mp4,right,left\n")
    assert pair_jobs(pairs)[0].sources == {"expression_from": str(tmp_path / "s.mp4"),
                                           "target_face": "right", "source_face": "left"}
    pairs.write_text('target,expression_from,source_face\nt.mp4,s.mp4,"-3,4"\n')
    with pytest.raises(BatchError, match="pairs.csv row 1: source_face must be left"):
        pair_jobs(pairs)


def test_missing_manifest_and_no_clips(tmp_path):
    with pytest.raises(BatchError, match="manifest .*nope.csv does not exist"):
        clip_jobs(manifest=tmp_path / "nope.csv")
    with pytest.raises(BatchError, match="no clips"):
        clip_jobs([])
    with pytest.raises(BatchError, match="no track files"):
        export_jobs([])


def test_names_clash_also_in_case_and_across_sources(tmp_path):
    man = tmp_path / "m.csv"
    man.write_text("video\nother/Take1.mp4\n")
    with pytest.raises(BatchError, match="two clips have the name 'Take1'.*take1.mp4.*Take1.mp4"):
        clip_jobs(["take1.mp4"], man)
    with pytest.raises(BatchError, match="name 'x'"):
        export_jobs(["a/x.npz", "b/x.npz"])


def test_pairs_manifest(tmp_path):
    man = tmp_path / "pairs.csv"
    man.write_text("target,expression_from,source_track,identity_label,name\n"
                   "t.mp4,s.mp4,s.npz,,\n"
                   "t.mp4,,,id03,t_as_id03\n")
    a, b = pair_jobs(man)
    assert a.name == "t" and a.target == tmp_path / "t.mp4"
    assert a.sources == {"expression_from": str(tmp_path / "s.mp4"),
                         "source_track": str(tmp_path / "s.npz")}
    assert b.name == "t_as_id03" and b.sources == {"identity_label": "id03"}  # not a path


@pytest.mark.parametrize("rows, message", [
    ("t.mp4,,,\n", "nothing to transfer"),
    ("t.mp4,,s.npz,\n", "source_track needs expression_from"),
    ("t.mp4,s.mp4,,\nt.mp4,s2.mp4,,\n", "two clips have the name 't'"),
    ("t.mp4,,,v.mp4\n", None),
])
def test_bad_pairs(tmp_path, rows, message):
    man = tmp_path / "pairs.csv"
    man.write_text("target,expression_from,source_track,identity_from\n" + rows)
    if message is None:
        assert pair_jobs(man)[0].sources == {"identity_from": str(tmp_path / "v.mp4")}
        return
    with pytest.raises(BatchError, match=message):
        pair_jobs(man)


def test_summary_round_trip_and_one_line_errors(tmp_path):
    rows = [Row("a", "done", 120, 25.0, 3.5, 0.93, output="/o/a.npz", job="1f2e3d"),
            Row("b", "failed", error="video /x/b.mp4 does not exist\n  (details)"),
            Row("c", "cancelled")]
    p = write_summary(tmp_path / "summary.csv", rows)
    assert p.read_text().splitlines()[0] == \
        "clip,frames,fps,seconds,mean_confidence,status,error,output,job"
    back = read_summary(p)
    assert back == [Row("a", "done", 120, 25.0, 3.5, 0.93, output="/o/a.npz", job="1f2e3d"),
                    Row("b", "failed", error="video /x/b.mp4 does not exist (details)"),
                    Row("c", "cancelled")]
    with pytest.raises(ValueError, match="status must be one of"):
        Row("d", "ok")
