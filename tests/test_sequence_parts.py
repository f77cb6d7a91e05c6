"""An image sequence written through a folder that outlives an interruption
(facetransfer.io.sequence_parts)."""

import errno
import json

import numpy as np
import pytest
from PIL import Image

from _writing import write_rest

from facetransfer.errors import VideoError
from facetransfer.io import sequence_parts as sp
from facetransfer.io.video_parts import PartsBusy


def _frames(n=7, h=24, w=32, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def _write(folder, out, frames, *, stop=None, overwrite=True):
    """Write ``frames`` from where the folder's frames end; Ctrl-C before frame ``stop``."""
    w = sp.SequenceWriter(folder, out, (frames[0].shape[1], frames[0].shape[0]),
                          n_frames=len(frames), overwrite=overwrite)
    return w, write_rest(w, frames, stop=stop, marked=lambda i: i % 3 == 0)


def _read(pattern, n):
    return [np.asarray(Image.open(str(pattern) % i)) for i in range(n)]


def test_an_interrupted_sequence_continues_and_equals_one_written_at_once(tmp_path):
    frames, folder, out = _frames(), tmp_path / "cache", tmp_path / "out" / "f%04d.png"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, out, frames, stop=5)
    assert sp.kept_frames(folder, "f%04d.png", 7) == [True, False, False, True, False]
    assert not out.parent.exists() or not any(out.parent.iterdir())  # nothing in place yet
    (folder / ".f0005.png.tmp").write_bytes(b"half a frame")  # what a killed writer leaves
    w, start = _write(folder, out, frames)
    assert start == 5 and w.resumed == 5 and w.marked == 3 and not folder.exists()
    assert w.result.n_frames == 7 and w.result.kind == "images"
    for got, want in zip(_read(out, 7), frames):
        np.testing.assert_array_equal(got, want)
    whole, _ = _write(tmp_path / "c2", tmp_path / "once%04d.png", frames)
    assert whole.resumed == 0
    for i in range(7):
        assert (out.parent / (out.name % i)).read_bytes() == \
            (tmp_path / f"once{i:04d}.png").read_bytes()


def test_frames_after_a_missing_one_and_another_sequences_are_not_taken_up(tmp_path):
    frames, folder, out = _frames(), tmp_path / "cache", tmp_path / "f%03d.png"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, out, frames, stop=6)
    (folder / "f002.png").unlink()
    assert sp.kept_frames(folder, "f%03d.png", 7) == [True, False]
    assert sorted(p.name for p in folder.iterdir()) == ["f000.png", "f001.png", "frames.json",
                                                        "lock", "marks"]
    assert (folder / "marks").read_bytes() == b"10"
    (folder / "f002.png").write_bytes(b"a frame whose mark a kill prevented")
    assert sp.kept_frames(folder, "f%03d.png", 7) == [True, False]
    assert not (folder / "f002.png").exists()
    assert sp.kept_frames(folder, "g%03d.png", 7) == []  # another pattern: start again
    assert sp.kept_frames(folder, "f%03d.png", 7) == []
    (folder / "frames.json").write_text("{not json")
    assert sp.kept_frames(folder, "f%03d.png", 7) == []
    assert json.loads((folder / "frames.json").read_text()) == {"name": "f%03d.png",
                                                                 "n_frames": 7}
    assert (folder / "marks").read_bytes() == b""


def test_an_older_longer_sequence_is_replaced_only_at_the_end(tmp_path):
    frames, folder = _frames(4), tmp_path / "cache"
    for i in range(6):
        (tmp_path / f"f{i:02d}.png").write_bytes(b"old")
    (tmp_path / "other.png").write_bytes(b"keep")
    with pytest.raises(ValueError, match="--overwrite"):
        sp.SequenceWriter(folder, tmp_path / "f%02d.png", (32, 24), n_frames=4)
    with pytest.raises(KeyboardInterrupt):
        _write(folder, tmp_path / "f%02d.png", frames, stop=2)
    assert all((tmp_path / f"f{i:02d}.png").read_bytes() == b"old" for i in range(6))
    _write(folder, tmp_path / "f%02d.png", frames)
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".png") == \
        ["f00.png", "f01.png", "f02.png", "f03.png", "other.png"]


def test_what_a_sequence_writer_refuses(tmp_path):
    with pytest.raises(VideoError, match="not an image sequence"):
        sp.SequenceWriter(tmp_path / "c", tmp_path / "o.mp4", (32, 24), n_frames=3)
    w = sp.SequenceWriter(tmp_path / "c", tmp_path / "f%02d.png", (32, 24), n_frames=2)
    with pytest.raises(PartsBusy, match="another process"):
        sp.SequenceWriter(tmp_path / "c", tmp_path / "f%02d.png", (32, 24), n_frames=2)
    with pytest.raises(VideoError, match="does not match the size"):
        w.write(np.zeros((8, 8, 3), np.uint8))
    w.write(_frames(1)[0])
    with pytest.raises(VideoError, match="1 frames were written, not 2"):
        w.close()
    assert not (tmp_path / "f00.png").exists() and (tmp_path / "c" / "f00.png").exists()


def test_a_frame_that_cannot_be_written_says_where_and_the_way_around(tmp_path, monkeypatch):
    w = sp.SequenceWriter(tmp_path / "c", tmp_path / "f%02d.png", (32, 24), n_frames=2)

    def full(self, fp, *a, **k):
        open(fp, "wb").write(b"par")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full)
    with pytest.raises(VideoError, match=r"frame f00.png of .*f%02d.png in the render cache "
                                         r".*FACETRANSFER_RENDER_CACHE=off"):
        w.write(_frames(1)[0])
    assert w.done == 0 and not (tmp_path / "c" / ".f00.png.tmp").exists()
    w.close(commit=False)
    assert not (tmp_path / "c").exists()  # nothing to continue from


@pytest.mark.parametrize("suffix", [".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg"])
def test_each_file_type_of_a_sequence_is_written(tmp_path, suffix):
    """Every image type a sequence takes: lossless ones exact, JPEG at quality 95 (within a
    few levels on a smooth image; PIL's default, 75, is coarser)."""
    from facetransfer.io.video import IMAGE_SUFFIXES, save_frame_image

    assert suffix in IMAGE_SUFFIXES
    y, x = np.mgrid[0:48, 0:64]
    img = np.stack([x * 4, y * 5, (x + y) * 2], axis=-1).astype(np.uint8)
    save_frame_image(img, tmp_path / "f.tmp", suffix=suffix)  # the type from ``suffix``
    back = np.asarray(Image.open(tmp_path / "f.tmp").convert("RGB")).astype(int)
    err = np.abs(back - img).max()
    assert err == 0 if suffix not in (".jpg", ".jpeg") else 0 < err <= 6


def test_two_runs_writing_one_new_sequence_at_once_the_later_is_refused(tmp_path):
    """Two runs of one new sequence, without --overwrite, both passed the check at their start
    (no frames yet): the one that finished later replaced the other's frames without being
    asked to (and, shorter, left none of them; longer, a mix till its moves ended). Now it is
    refused where it places its frames, the first run's kept, its own kept in the cache."""
    from facetransfer.io.video import VideoWriter

    out, long_, short = tmp_path / "out" / "f%03d.png", _frames(6, seed=1), _frames(3, seed=2)
    late = sp.SequenceWriter(tmp_path / "c1", out, (32, 24), n_frames=3, overwrite=False)
    _write(tmp_path / "c2", out, long_, overwrite=False)         # the other run ends first
    for f in short:
        late.write(f)
    with pytest.raises(VideoError, match="meanwhile by another run .6 files.*--overwrite"):
        late.close()
    assert len(list(out.parent.iterdir())) == 6
    for got, want in zip(_read(out, 6), long_):
        np.testing.assert_array_equal(got, want)
    assert sp.kept_frames(tmp_path / "c1", "f%03d.png", 3) == [False] * 3   # continued later
    direct = tmp_path / "direct" / "g%03d.png"
    late = VideoWriter(direct, 25.0, (32, 24), overwrite=False)
    with VideoWriter(direct, 25.0, (32, 24), overwrite=False) as first:
        for f in long_:
            first.write(f)
    for f in short:
        late.write(f)
    with pytest.raises(VideoError, match="meanwhile by another run"):
        late.close()
    assert sorted(p.name for p in direct.parent.iterdir()) == [f"g{i:03d}.png" for i in range(6)]
    for got, want in zip(_read(direct, 6), long_):
        np.testing.assert_array_equal(got, want)


def test_frames_are_placed_under_a_lock_on_their_folder(tmp_path, monkeypatch):
    """Each frame moved beside the pattern with the folder locked (``flock``), so a second run
    placing the same pattern waits and a reader of the sequence sees one run's frames: with the
    lock taken out, every test above still passed."""
    import fcntl
    import os
    import shutil

    from facetransfer.io import video as io_video

    out, seen, move = tmp_path / "out" / "f%03d.png", [], shutil.move
    out.parent.mkdir()

    def move_checked(src, dst):
        fd = os.open(out.parent, os.O_RDONLY | os.O_DIRECTORY)   # another run's attempt
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            seen.append("free")
        except BlockingIOError:
            seen.append("locked")
        finally:
            os.close(fd)
        return move(src, dst)

    monkeypatch.setattr(io_video.shutil, "move", move_checked)
    frames = _frames(4)
    _write(tmp_path / "c", out, frames)
    assert seen == ["locked"] * 4
    for got, want in zip(_read(out, 4), frames):
        np.testing.assert_array_equal(got, want)


def test_frames_are_placed_without_a_lock_where_the_platform_has_none(tmp_path, monkeypatch):
    """Where ``fcntl`` cannot be imported (not POSIX), the frames are placed all the same,
    without the folder's lock (before, the import's error stopped every sequence's end)."""
    import sys

    monkeypatch.setitem(sys.modules, "fcntl", None)      # import fcntl: ImportError
    out = tmp_path / "out" / "f%03d.png"
    frames = _frames(3)
    _write(tmp_path / "c", out, frames)
    for got, want in zip(_read(out, 3), frames):
        np.testing.assert_array_equal(got, want)
