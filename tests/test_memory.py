"""Decoded frames past the memory budget kept in an unnamed file (facetransfer.io.memory)."""

import errno
import os

import numpy as np
import pytest

from facetransfer.errors import VideoError
from facetransfer.io import memory
from facetransfer.io.video import read_video, write_video


def _clip(tmp_path, n=9):
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 255, size=(n, 16, 24, 3), dtype=np.uint8)
    return write_video(tmp_path / "v.mp4", frames, 10)


def test_a_clip_past_the_budget_is_decoded_into_an_unnamed_file(tmp_path, monkeypatch):
    p = _clip(tmp_path)
    in_memory, _ = read_video(p)
    spill = tmp_path / "frames"
    spill.mkdir()
    monkeypatch.setenv("FACETRANSFER_TMPDIR", str(spill))
    monkeypatch.setenv("FACETRANSFER_FRAME_MEMORY", "0")
    on_disk, _ = read_video(p)
    assert not isinstance(in_memory, np.memmap) and isinstance(on_disk, np.memmap)
    np.testing.assert_array_equal(on_disk, in_memory)
    assert list(spill.iterdir()) == []            # nothing named, nothing left behind
    monkeypatch.setenv("FACETRANSFER_FRAME_MEMORY", str(in_memory.nbytes))
    again, _ = read_video(p)                      # exactly the budget: in memory
    assert not isinstance(again, np.memmap)


def test_frame_array_and_its_growth_keep_the_frames(tmp_path, monkeypatch):
    monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path))
    small = memory.frame_array(2, (3, 4, 3), what="v", budget=2 * 36)
    big = memory.frame_array(3, (3, 4, 3), what="v", budget=2 * 36)
    assert type(small) is np.ndarray and isinstance(big, np.memmap)
    assert big.shape == (3, 3, 4, 3) and big.dtype == np.uint8
    big[:] = np.arange(big.size, dtype=np.uint8).reshape(big.shape)
    grown = memory.grow_frames(big, 3, 7, (3, 4, 3), what="v", budget=0)
    assert isinstance(grown, np.memmap) and grown.shape == (7, 3, 4, 3)
    np.testing.assert_array_equal(grown[:3], big)


def _vm_flags(a: np.ndarray) -> list[str] | None:
    """The kernel's VmFlags of the mapping holding ``a``'s middle byte (None: not found;
    advice covers the whole 2 MB pages inside an array, not its first bytes)."""
    addr = a.__array_interface__["data"][0] + a.nbytes // 2
    flags, inside = None, False
    with open("/proc/self/smaps") as fh:
        for line in fh:
            head = line.split()[0]
            if "-" in head and all(c in "0123456789abcdef-" for c in head):
                lo, hi = (int(x, 16) for x in head.split("-"))
                inside = lo <= addr < hi
            elif inside and line.startswith("VmFlags:"):
                flags = line.split()[1:]
    return flags


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps"), reason="Linux only")
def test_frames_in_memory_are_private_and_not_advised_into_huge_pages():
    """NumPy advises huge pages for its large arrays ("hg"); a clip's frames get ordinary
    pages (the kernel's compaction for that advice stalled the first write of the frames), in
    a private map ("sh": shared memory, whose first touches cost more)."""
    frames = memory.frame_array(8, (480, 640, 3), what="v", budget=1 << 30)   # 7.4 MB
    frames[:] = 7                                   # writable, uninitialised until written
    assert type(frames) is np.ndarray and frames.shape == (8, 480, 640, 3)
    assert (frames == 7).all()
    plain = np.empty(frames.shape, np.uint8)
    plain[:] = 7
    mine, numpy_s = _vm_flags(frames), _vm_flags(plain)
    assert mine is not None and "hg" not in mine and "sh" not in mine
    if numpy_s is None or "hg" not in numpy_s:
        pytest.skip("this NumPy or kernel advises no huge pages: nothing to compare")


def test_a_disk_without_room_is_one_clear_error(tmp_path, monkeypatch):
    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path))
    monkeypatch.setattr(os, "posix_fallocate", full, raising=False)
    with pytest.raises(VideoError, match=r"video clip\.mp4 needs 2\.0 GiB on disk .*"
                                         r"FACETRANSFER_TMPDIR"):
        memory.frame_array(2, (1 << 30,), what="video clip.mp4", budget=0)
    assert list(tmp_path.iterdir()) == []


def test_a_missing_frame_folder_is_named(tmp_path, monkeypatch):
    monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path / "none"))
    with pytest.raises(VideoError, match=r"video a\.mp4 .*FACETRANSFER_TMPDIR .*none is not a "
                                         r"folder"):
        memory.frame_array(2, (3,), what="video a.mp4", budget=0)


def test_a_file_system_that_cannot_reserve_is_written_as_is(tmp_path, monkeypatch):
    def unsupported(fd, offset, length):
        raise OSError(errno.EOPNOTSUPP, os.strerror(errno.EOPNOTSUPP))

    monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path))
    monkeypatch.setattr(os, "posix_fallocate", unsupported, raising=False)
    a = memory.frame_array(3, (4, 5, 3), what="v", budget=0)
    a[:] = 7
    assert isinstance(a, np.memmap) and int(a.sum()) == 7 * a.size


@pytest.mark.parametrize("text, want", [("512M", 512 << 20), ("4G", 4 << 30), ("1.5g", 3 << 29),
                                        ("100000", 100000), ("2GiB", 2 << 30), (" 7k ", 7168)])
def test_parse_bytes(text, want):
    assert memory.parse_bytes(text) == want


def test_a_bad_frame_memory_setting_names_the_variable(monkeypatch):
    monkeypatch.setenv("FACETRANSFER_FRAME_MEMORY", "lots")
    with pytest.raises(VideoError, match="FACETRANSFER_FRAME_MEMORY .* got 'lots'"):
        memory.frame_budget()


def _cgroups(tmp_path, proc, files):
    tmp_path.mkdir()
    (tmp_path / "cgroup").write_text(proc)
    for rel, text in files.items():
        f = tmp_path / "fs" / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    return str(tmp_path / "cgroup"), str(tmp_path / "fs")


def test_cgroup_headroom_reads_v1_and_v2_limits(tmp_path):
    v1 = _cgroups(tmp_path / "a", "5:cpu:/\n4:memory:/box\n0::/\n",
                  {"memory/box/memory.limit_in_bytes": "6442450944\n",
                   "memory/box/memory.usage_in_bytes": "1073741824\n"})
    assert memory.cgroup_headroom(*v1) == 5 << 30
    v2 = _cgroups(tmp_path / "b", "0::/user/job\n",
                  {"user/job/memory.max": "2147483648\n", "user/job/memory.current": "1000\n"})
    assert memory.cgroup_headroom(*v2) == (2 << 30) - 1000
    unlimited = _cgroups(tmp_path / "c", "0::/j\n", {"j/memory.max": "max\n",
                                                    "j/memory.current": "5\n"})
    assert memory.cgroup_headroom(*unlimited) is None
    v1_unlimited = _cgroups(tmp_path / "d", "4:memory:/\n",
                            {"memory/memory.limit_in_bytes": "9223372036854771712\n",
                             "memory/memory.usage_in_bytes": "5\n"})
    assert memory.cgroup_headroom(*v1_unlimited) is None
    assert memory.cgroup_headroom(str(tmp_path / "none"), str(tmp_path)) is None


def test_the_budget_is_a_share_of_the_least_memory_known(monkeypatch):
    monkeypatch.delenv("FACETRANSFER_FRAME_MEMORY", raising=False)
    monkeypatch.setattr(memory, "available_bytes", lambda: 20 << 30)
    monkeypatch.setattr(memory, "cgroup_headroom", lambda: 4 << 30)
    assert memory.frame_budget() == int(memory.FRAME_MEMORY_FRACTION * (4 << 30))
    monkeypatch.setattr(memory, "cgroup_headroom", lambda: None)
    assert memory.frame_budget() == int(memory.FRAME_MEMORY_FRACTION * (20 << 30))
