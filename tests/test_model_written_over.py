"""A model file written over in place while a one-process command runs (``track``,
``transfer``, ``puppet``): its core is mapped from the file (facetransfer.model.load_model),
so it reads the new bytes from then on; the command writes no result made of two models
(facetransfer.io.atomic.commit_checks; BENCHMARKS.md, "Fifty-fourth session (helper
cache54)")."""

from __future__ import annotations

import os
import shutil

import pytest

from facetransfer import model as model_module
from facetransfer.cli.main import main
from facetransfer.io import atomic

from conftest import clip_with_points


@pytest.fixture(scope="module")
def small_clip(quick_model, tmp_path_factory):
    """An 8-frame synthetic clip and a POINTS.json of its first frame's landmarks."""
    return clip_with_points(quick_model, 8, 5, tmp_path_factory.mktemp("overwritten"))


def _write_over(path, same: bool = False) -> None:
    """Write the first 64 numbers of ``path``'s core in place, the same inode, as ``cp`` onto
    it does; its time a second on (a clock coarser than the run is no excuse). Each is
    changed in its last bit, so that the tracker goes on as with any model; with ``same``,
    the bytes written are those it held (an identical copy written over it)."""
    import numpy as np

    from facetransfer.io.npz import mapped_members

    with np.load(path) as z:
        core = mapped_members(path, z, 0)["core"]
    at, step = core.base.offset, core.dtype.itemsize
    st = os.stat(path)
    with open(path, "r+b") as fh:
        fh.seek(at)
        block = bytearray(fh.read(64 * step))
        for i in range(0, 0 if same else len(block), step):
            block[i] ^= 1                  # little-endian: the mantissa's last bit
        fh.seek(at)
        fh.write(block)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))


def _track_writing_over(monkeypatch, path, replace=None, change=None):
    """The KLT tracker, the model file written over in place (or, with ``replace``, replaced
    by a rename of that file onto it; with ``change``, changed so) at its third frame pair."""
    from facetransfer.track import tracker

    real, calls = tracker.FaceTracker.track_pair, []
    change = change or ((lambda: _write_over(path)) if replace is None
                        else (lambda: os.replace(replace, path)))

    def track_pair(self, *a, **k):
        calls.append(1)
        if len(calls) == 3:
            change()
        return real(self, *a, **k)

    monkeypatch.setattr(tracker.FaceTracker, "track_pair", track_pair)


def test_a_track_is_not_written_after_its_model_file_was_written_over(
        small_clip, quick_model_path, tmp_path, monkeypatch, capsys):
    """Before, ``track --model M.npz`` wrote the track (exit 0) after M.npz was written over
    in place mid-run: the model it went on with read the new bytes, and the track named the
    old model's hash. Now one line names the file, exit 2, and no track is written (nor kept in
    the track cache: the same check runs for every output)."""
    video, points, _ = small_clip
    monkeypatch.setattr(model_module, "MAP_MIN_BYTES", 1024)   # the quick model's core mapped
    mine = tmp_path / "M.npz"
    shutil.copyfile(quick_model_path, mine)
    out = tmp_path / "t.npz"
    _track_writing_over(monkeypatch, mine)
    code = main(["track", str(video), "--model", str(mine), "--out", str(out), "--init",
                 str(points), "--passes", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert len(err) == 1 and f"model file {mine} was written over while this command ran" \
        in err[0]
    assert atomic._CHECKS is None                       # the command's checks end with it


def test_a_model_file_replaced_or_read_whole_is_no_reason_to_refuse(
        small_clip, quick_model_path, quick_model, tmp_path, monkeypatch):
    """No refusal where the run's model is intact: a file replaced by a rename (``save``
    writes so: the mapped file is kept as it was), or one written over in place whose arrays
    were read whole (smaller than :data:`~facetransfer.model.MAP_MIN_BYTES`)."""
    from facetransfer.track import Track

    video, points, _ = small_clip
    mine, other = tmp_path / "M.npz", tmp_path / "other.npz"
    for mapped, replace in ((1024, other), (None, None)):
        if mapped is not None:
            monkeypatch.setattr(model_module, "MAP_MIN_BYTES", mapped)
        else:
            monkeypatch.undo()
        shutil.copyfile(quick_model_path, mine)
        shutil.copyfile(quick_model_path, other)
        _track_writing_over(monkeypatch, mine, replace)
        out = tmp_path / f"t{mapped}.npz"
        assert main(["track", str(video), "--model", str(mine), "--out", str(out), "--init",
                     str(points), "--passes", "1"]) == 0
        assert Track.load(out).model_hash == quick_model.content_hash


def test_outside_a_command_a_library_caller_is_not_checked(quick_model_path, tmp_path,
                                                           monkeypatch):
    """The check belongs to a command's run (:func:`facetransfer.io.atomic.commit_checks`):
    a library's caller that loads a model adds none, and within a scope the check refuses an
    output once the model's file is written over, and passes before."""
    from facetransfer.errors import ModelFileError

    monkeypatch.setattr(model_module, "MAP_MIN_BYTES", 1024)
    mine = tmp_path / "M.npz"
    shutil.copyfile(quick_model_path, mine)
    model_module.load_model(mine)
    assert atomic._CHECKS is None
    with atomic.commit_checks():
        m = model_module.load_model(mine)
        atomic.write_text_atomic(tmp_path / "before.txt", "x")
        _write_over(mine)
        with pytest.raises(ModelFileError, match="was written over"):
            atomic.write_text_atomic(tmp_path / "after.txt", "x")
    assert (tmp_path / "before.txt").is_file() and not (tmp_path / "after.txt").exists()
    assert not list(tmp_path.glob(".after*"))           # its temporary file removed
    del m


def test_an_image_sequences_frames_are_not_placed_after_it(quick_model_path, tmp_path,
                                                           monkeypatch):
    """An image sequence's frames are put in place by the writer itself (not through
    ``atomic_path``): they too wait for the checks, so none of a plate rendered with a model
    written over reaches its pattern."""
    from facetransfer.errors import ModelFileError
    from facetransfer.io.video import place_sequence

    monkeypatch.setattr(model_module, "MAP_MIN_BYTES", 1024)
    mine, done = tmp_path / "M.npz", tmp_path / "done"
    shutil.copyfile(quick_model_path, mine)
    done.mkdir()
    for i in range(2):
        (done / f"f{i:04d}.png").write_bytes(b"frame")
    with atomic.commit_checks():
        m = model_module.load_model(mine)
        _write_over(mine)
        with pytest.raises(ModelFileError, match="was written over"):
            place_sequence(done, tmp_path / "out" / "f%04d.png", 2)
    assert sorted(p.name for p in done.iterdir()) == ["f0000.png", "f0001.png"]
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
    del m


def test_a_model_file_touched_or_copied_over_identically_is_no_reason_to_refuse(
        small_clip, quick_model_path, quick_model, tmp_path, monkeypatch):
    """A model file whose identity changed mid-run but not its content: touched (its time
    only), an identical copy written over it (``cp`` of the same file: the same inode), the
    same bytes written back. Before, each was refused as written over (exit 2, no track);
    now its content is read once and the track written."""
    from facetransfer.track import Track

    video, points, _ = small_clip
    monkeypatch.setattr(model_module, "MAP_MIN_BYTES", 1024)   # the quick model's core mapped
    mine = tmp_path / "M.npz"

    def touch():
        st = os.stat(mine)
        os.utime(mine, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))

    def copy_over():
        inode = os.stat(mine).st_ino
        shutil.copyfile(quick_model_path, mine)
        touch()
        assert os.stat(mine).st_ino == inode

    for name, change in (("touched", touch), ("copied", copy_over),
                         ("same bytes", lambda: _write_over(mine, same=True))):
        shutil.copyfile(quick_model_path, mine)
        _track_writing_over(monkeypatch, mine, change=change)
        out = tmp_path / f"t-{name}.npz"
        assert main(["track", str(video), "--model", str(mine), "--out", str(out), "--init",
                     str(points), "--passes", "1"]) == 0, name
        assert Track.load(out).model_hash == quick_model.content_hash


def test_a_changed_identity_is_read_once_and_another_content_refused(quick_model_path,
                                                                     tmp_path, monkeypatch):
    """The content is read once after the file's identity changed (not per output), the
    identity it then has taken as the model's; a file then written over with other content is
    refused as before."""
    from facetransfer.errors import ModelFileError

    monkeypatch.setattr(model_module, "MAP_MIN_BYTES", 1024)
    real, reads = model_module._content_hash, []
    monkeypatch.setattr(model_module, "_content_hash",
                        lambda *a: reads.append(1) or real(*a))
    mine = tmp_path / "M.npz"
    shutil.copyfile(quick_model_path, mine)
    with atomic.commit_checks():
        m = model_module.load_model(mine)
        reads.clear()                                   # the load's own check
        _write_over(mine, same=True)
        for k in range(3):
            atomic.write_text_atomic(tmp_path / f"same{k}.txt", "x")
        assert len(reads) == 1
        _write_over(mine)
        with pytest.raises(ModelFileError, match="was written over"):
            atomic.write_text_atomic(tmp_path / "after.txt", "x")
    assert not (tmp_path / "after.txt").exists()
    del m
