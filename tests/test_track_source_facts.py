"""A track keeps what its exports read of its clip (forty-fourth session): the first frame
number of a plate (1001) and the clip's start timecode are recorded when it is tracked
(``source_first_frame``, ``source_timecode``), so that a take or a USD of it is the same after
the clip moved, was deleted or another clip took its path; and ``export`` makes the activations
of a track that lacks them, as the library's ``export_track`` does."""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from conftest import clip_with_points  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.source_facts import SourceFacts  # noqa: E402
from facetransfer.track import Track  # noqa: E402


@pytest.fixture(scope="module")
def clip(arkit_model, tmp_path_factory):
    """A 4-frame synthetic clip of the ARKit model and the POINTS.json of its first frame
    (the optical-flow tracker from them: no detector needed)."""
    return clip_with_points(arkit_model, 4, 3, tmp_path_factory.mktemp("facts"))


def _clip_at(kind: str, folder: Path, frames, *, first: int = 1001,
             timecode: str = "01:00:00:00") -> Path:
    """The clip as a PNG plate numbered from ``first`` or a QuickTime with a ``timecode``."""
    from facetransfer.io.video import VideoOptions, write_video
    from test_video_sequence import _plate

    if kind == "plate":
        _plate(folder, frames, first=first)
        return folder / "sh010.####.png"
    folder.mkdir(parents=True, exist_ok=True)
    write_video(folder / "clip.mov", frames, 25.0, options=VideoOptions(crf=0, timecode=timecode))
    return folder / "clip.mov"


def _exports(track_file: Path, model: Path, out: Path, capsys) -> dict[str, bytes]:
    """The track's Live Link take and USD (``--timecode source``, the default), by bytes, and
    what export said (the folder's name taken out)."""
    out.mkdir()
    files, said = {}, []
    for name in ("take.csv", "face.usda"):
        assert main(["export", str(track_file), "--model", str(model), "--out",
                     str(out / name)]) == 0
        said += capsys.readouterr().out.replace(str(out), "OUT").splitlines()
        files[name] = (out / name).read_bytes()
    return files, said


@pytest.mark.parametrize("kind, facts, first_row, start", [
    ("plate", SourceFacts(1001, None), "00:00:00:00.000", 1001),
    ("video", SourceFacts(0, "01:00:00:00"), "01:00:00:00.000", 0)])
def test_a_tracks_exports_are_the_same_after_its_clip_moved(kind, facts, first_row, start, clip,
                                                            arkit_model, arkit_model_path, tmp_path,
                                                            capsys, monkeypatch):
    """Tracked, exported, the clip moved away, exported again, another clip put at the old
    path (another numbering, another timecode), exported again: the same take and USD each
    time (before: numbered from 0 and untimed once the clip was gone, the other clip's
    numbering once it was there), and nothing said of where they were read."""
    pytest.importorskip("pxr", reason="usd-core is not installed (extra [usd])")
    from facetransfer.export.livelink import read_livelink

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")   # undone after (the CLI sets it)
    video, points, synth = clip
    src = _clip_at(kind, tmp_path / "shot", synth.frames)
    tp = tmp_path / "t.npz"
    assert main(["track", str(src), "--model", str(arkit_model_path), "--tracker", "klt", "--init",
                 str(points), "--passes", "1", "--no-progress", "--out", str(tp)]) == 0
    capsys.readouterr()
    track = Track.load(tp)
    assert track.source == str(src) and track.source_facts == facts
    with np.load(tp) as z:
        assert int(z["source_first_frame"]) == facts.first_frame
        assert str(z["source_timecode"]) == (facts.timecode or "")
    before, said = _exports(tp, arkit_model_path, tmp_path / "before", capsys)
    take = read_livelink(tmp_path / "before" / "take.csv")
    assert take.timecodes[0] == first_row and not any("note:" in s for s in said)
    assert f"startTimeCode = {start}\n" in before["face.usda"].decode()

    shutil.move(tmp_path / "shot", tmp_path / "elsewhere")        # the project moved
    assert _exports(tp, arkit_model_path, tmp_path / "moved", capsys) == (before, said)
    _clip_at(kind, tmp_path / "shot", synth.frames[::-1], first=1, timecode="02:00:00:00")
    assert _exports(tp, arkit_model_path, tmp_path / "other", capsys) == (before, said)


def test_an_older_track_reads_its_clip_and_says_where(arkit_model, make_arkit_track, tmp_path,
                                                     capsys):
    """A track written before tracks recorded the numbering: export reads it from the clip at
    the track's path, saying so; where that is gone, or is a clip of another size (another
    clip), it numbers from 0 with no timecode, saying why."""
    pytest.importorskip("pxr", reason="usd-core is not installed (extra [usd])")
    import cv2

    track, _, _ = make_arkit_track(arkit_model, 3)
    W, H = track.frame_size
    plate = tmp_path / "plate"
    plate.mkdir()
    for n in (1001, 1002, 1003):
        cv2.imwrite(str(plate / f"p.{n:04d}.png"), np.full((H, W, 3), 90, np.uint8))
    src = plate / "p.####.png"
    tp = tmp_path / "old.npz"
    dataclasses.replace(track, source=str(src)).save(tp)
    with np.load(tp) as z:
        assert "source_first_frame" not in z.files and "source_timecode" not in z.files
    assert Track.load(tp).source_facts is None
    arkit_model.save(tmp_path / "m.npz")

    def export(name):
        out = tmp_path / name
        assert main(["export", str(tp), "--model", str(tmp_path / "m.npz"), "--out",
                     str(out)]) == 0
        said = capsys.readouterr().out.splitlines()
        return out.read_text(), said

    older = ("note: the track records no first frame number or start timecode (made before "
             "tracks recorded them)")
    usda, said = export("a.usda")
    assert "startTimeCode = 1001\n" in usda
    assert said[0] == f"{older}: read from its clip {src}", said
    assert said[1].endswith(f", time codes from 1001, the first frame of {src}")
    for p in plate.iterdir():
        cv2.imwrite(str(p), np.full((H // 2, W // 2, 3), 90, np.uint8))
    usda, said = export("b.usda")
    assert "startTimeCode = 0\n" in usda
    assert said[0] == (f"{older} and the clip now at {src} is {W // 2}x{H // 2}, not the "
                       f"track's {W}x{H} (another clip): not read (numbered from 0, no "
                       "timecode)")
    shutil.rmtree(plate)
    usda, said = export("c.usda")
    assert "startTimeCode = 0\n" in usda
    assert said[0] == f"{older} and its clip {src} is not there: numbered from 0, no timecode"
    csv, said = export("d.csv")
    assert csv.splitlines()[1].startswith("00:00:00:00.000,")


def test_the_recorded_numbering_is_checked_when_a_track_is_read(arkit_model, make_arkit_track,
                                                                tmp_path):
    """A track file's ``source_first_frame`` and ``source_timecode`` are read back as written,
    and a negative first frame or a timecode that is none is refused naming the file."""
    from facetransfer.errors import TrackError

    track, _, _ = make_arkit_track(arkit_model, 2)
    for facts in (SourceFacts(1001, None), SourceFacts(0, "10:00:00;02"), SourceFacts()):
        tp = dataclasses.replace(track, source_facts=facts).save(tmp_path / "t.npz")
        assert Track.load(tp).source_facts == facts
    with np.load(tp) as z:
        arrays = dict(z)
    for key, bad, said in (("source_first_frame", np.int64(-1), "must be >= 0, got -1"),
                           ("source_timecode", np.array("soon"), "a timecode must read"),
                           ("source_timecode", np.float64(3.0), "must hold text")):
        p = tmp_path / f"bad_{key}.npz"
        np.savez(p, **{**arrays, key: bad})
        with pytest.raises(TrackError, match=f"track file {p}") as err:
            Track.load(p)
        assert said in str(err.value)
    with pytest.raises(TrackError, match="source_facts must be a SourceFacts"):
        dataclasses.replace(track, source_facts=(1001, None))



@pytest.mark.parametrize("kind, timecode, facts", [
    ("plate", None, SourceFacts(1001, None)),
    ("video", "01:00:00:00", SourceFacts(0, "01:00:00:00")),
    ("video", None, SourceFacts(0, None))])
def test_a_chunked_batch_track_records_its_clips_numbering(kind, timecode, facts, arkit_model,
                                                           make_arkit_track, tmp_path):
    """``batch track --chunk``: each chunk is tracked from decoded frames, which know no first
    frame number nor timecode (their tracks record none); the joined track records the clip's
    (a plate's first number, a video's start timecode, or none), as a clip tracked whole does,
    and its file keeps them. Before this test nothing checked it: a join keeping its first
    chunk's ``None`` would have left its exports to read the clip again (from 0 once it moved)."""
    from facetransfer.batch.chunks import plan_chunks
    from facetransfer.batch.jobs import ChunkResult, join_clip
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.track.project import take_frames

    track, _, _ = make_arkit_track(arkit_model, 9)
    frames = np.full((9, 24, 32, 3), 90, np.uint8)
    if kind == "plate":
        src = _clip_at("plate", tmp_path / "shot", frames)
    else:
        from facetransfer.io.video import VideoOptions, write_video

        src = tmp_path / "clip.mov"
        write_video(src, frames, 25.0, options=VideoOptions(crf=0, timecode=timecode))
    chunks = plan_chunks(9, 5, 2)
    assert len(chunks) == 3
    results = [ChunkResult(dataclasses.replace(
        take_frames(track, np.arange(c.start, c.stop)), source=str(src), source_facts=None), 1.0)
        for c in chunks]
    out = tmp_path / "joined.npz"
    join_clip(ClipJob("sh010", str(src)), str(out), arkit_model, chunks, results)
    joined = Track.load(out)
    assert joined.n_frames == 9 and joined.source_facts == facts
    with np.load(out) as z:
        assert int(z["source_first_frame"]) == facts.first_frame
        assert str(z["source_timecode"]) == (facts.timecode or "")

# ------------------------------------------------------------------ activations (CLI)
@pytest.fixture()
def bare(arkit_model, make_arkit_track, tmp_path):
    """A track of the ARKit model without activations (one recombined in Python) and the
    activations its weights were made from."""
    track, a, _ = make_arkit_track(arkit_model, 5)
    tp = tmp_path / "bare.npz"
    dataclasses.replace(track, blendshapes=None, blendshape_names=None,
                        source_facts=SourceFacts()).save(tp)
    return tp, a


def test_export_makes_the_activations_of_a_track_without_them(bare, arkit_model, arkit_model_path,
                                                              tmp_path, capsys, monkeypatch):
    """With --model, or with the default model for a track of it: the take holds the
    activations its weights were made from, and one line says how they were made (before:
    refused, while ``export_track`` made them)."""
    import facetransfer.default_model as dm
    from facetransfer.export.livelink import read_livelink

    tp, a = bare
    assert main(["export", str(tp), "--model", str(arkit_model_path), "--out",
                 str(tmp_path / "m.csv")]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[0] == (f"note: track {tp} holds no ARKit activations: made from its expression "
                       f"weights with the model {arkit_model_path}")
    assert said[1].startswith(f"wrote {tmp_path / 'm.csv'}: 5 frames (livelink)")
    np.testing.assert_allclose(read_livelink(tmp_path / "m.csv").activations, a, atol=1e-5)
    monkeypatch.setattr(dm, "load_default_model", lambda **kw: arkit_model)
    assert main(["export", str(tp), "--out", str(tmp_path / "d.csv")]) == 0
    assert capsys.readouterr().out.splitlines()[0].endswith(
        "made from its expression weights with the default model (ict-arkit)")
    assert (tmp_path / "d.csv").read_bytes() == (tmp_path / "m.csv").read_bytes()


def test_export_refuses_a_track_whose_activations_cannot_be_made(bare, arkit_model, quick_model,
                                                                 arkit_model_path, tmp_path, capsys,
                                                                 monkeypatch):
    """One line, exit status 2, nothing written: a model whose expressions are not ARKit's, a
    track of another model than the default one without --model, weights of other shapes
    than the model's (named), a track without expressions."""
    import facetransfer.default_model as dm

    monkeypatch.setattr(dm, "load_default_model", lambda **kw: arkit_model)
    tp, _ = bare
    track = Track.load(tp)
    quick = tmp_path / "quick.npz"
    quick_model.save(quick)
    of_quick = tmp_path / "q.npz"
    n = track.n_frames
    dataclasses.replace(track, weights={m: np.zeros((n, r)) for m, r in
                                        zip(quick_model.mode_names, quick_model.ranks)},
                        model_hash=quick_model.content_hash).save(of_quick)
    short = tmp_path / "short.npz"
    dataclasses.replace(track, weights={**track.weights,
                                        "expression": track.weights["expression"][:, :10]},
                        model_hash="").save(short)
    posed = tmp_path / "posed.npz"
    dataclasses.replace(track, weights={"identity": track.weights["identity"],
                                        "pose": np.zeros((n, 2))},
                        mode_names=("identity", "pose")).save(posed)
    out = tmp_path / "x.csv"
    for argv, said in (
            ([of_quick, "--model", quick],
             f"track {of_quick} has no ARKit blendshape activations and its model cannot give "
             "them: the model's expressions are not ARKit blendshapes"),
            ([of_quick], f"track {of_quick} has no ARKit blendshape activations and was not "
             "made with the default model (ict-arkit): give the model it was tracked with "
             "(--model M.npz)"),
            ([short, "--model", arkit_model_path],
             f"track {short} was made with another model: its weights of mode 'expression' "
             f"have 10 components, the model's {arkit_model.ranks[1]}"),
            ([posed], f"track {posed} has no ARKit blendshape activations and no expression "
             "weights to make them from (its modes: identity, pose)")):
        assert main(["export", *map(str, argv), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0] and "Traceback" not in err[0], err
        assert not out.exists()


def test_a_batch_project_moved_exports_its_plate_as_before(clip, arkit_model_path, tmp_path, capsys,
                                                           monkeypatch):
    """``batch track`` of a plate numbered from 1001, the project (plate, manifest, tracks)
    moved to another folder, the plate's old path gone: ``batch export`` of the kept track
    writes the USD it wrote before the move, its time codes from 1001 (before: from 0)."""
    pytest.importorskip("pxr", reason="usd-core is not installed (extra [usd])")
    import functools

    from facetransfer.batch import cluster as batch_cluster

    monkeypatch.setattr(batch_cluster, "open_client",        # worker threads, no network
                        functools.partial(batch_cluster.open_client, processes=False))
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    _, points, synth = clip
    proj = tmp_path / "proj"
    _clip_at("plate", proj / "plate", synth.frames)
    shutil.copy2(points, proj / "points.json")
    (proj / "clips.csv").write_text("video,init,name\nplate/sh010.####.png,points.json,sh010\n")

    def export(root):
        code = main(["batch", "export", str(root / "tracks" / "sh010.npz"), "--format", "usd",
                     "--model", str(arkit_model_path), "--out", str(root / "usd"), "--no-progress"])
        assert code == 0, capsys.readouterr().err
        return (root / "usd" / "sh010.usd").read_bytes()

    assert main(["batch", "track", "--manifest", str(proj / "clips.csv"), "--model",
                 str(arkit_model_path), "--out", str(proj / "tracks"), "--tracker", "klt",
                 "--passes", "1", "--no-progress"]) == 0
    assert Track.load(proj / "tracks" / "sh010.npz").source_facts == SourceFacts(1001, None)
    before = export(proj)
    shutil.move(proj, tmp_path / "moved")
    assert export(tmp_path / "moved") == before
    from pxr import Usd

    stage = Usd.Stage.Open(str(tmp_path / "moved" / "usd" / "sh010.usd"))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1001, 1004)
