"""File I/O: meshes, videos, atomic writes, and the CLI's one-line errors."""

import subprocess
import sys

from pathlib import Path

import numpy as np
import pytest

from facetransfer.errors import FaceTransferError, MeshError, VideoError
from facetransfer.io.atomic import atomic_path, write_text_atomic
from facetransfer.io.mesh import read_mesh, read_obj, read_obj_vertices, write_mesh
from facetransfer.io.video import read_video, video_info, write_video

QUAD_OBJ = """# a unit quad with UVs
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 2/2 3/3 4/4
"""


def test_read_obj_splits_quads_and_keeps_uvs(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text(QUAD_OBJ)
    m = read_obj(p)
    assert m.vertices.shape == (4, 3)
    assert np.array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])
    assert np.allclose(m.uvs, [[0, 0], [1, 0], [1, 1], [0, 1]])
    assert np.array_equal(read_obj_vertices(p), m.vertices)


def test_mesh_round_trip_obj_and_ply(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(10, 3))
    f = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]])
    for ext in ("obj", "ply"):
        p = write_mesh(tmp_path / f"m.{ext}", v, f)
        m = read_mesh(p)
        assert np.allclose(m.vertices, v, atol=1e-6)
        assert np.array_equal(m.faces, f)


@pytest.mark.parametrize("content,match", [
    ("", "empty"),
    ("v 0 0 nan\nv 1 1 1\n", "NaN"),
    ("# nothing\n", "no vertices"),
    ("v 0 0 x\n", "malformed"),
])
def test_bad_meshes(tmp_path, content, match):
    p = tmp_path / "bad.obj"
    p.write_text(content)
    with pytest.raises(MeshError, match=match):
        read_mesh(p)
    with pytest.raises(MeshError):
        read_mesh(tmp_path / "missing.obj")


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    write_text_atomic(target, "new")
    assert target.read_text() == "new"
    with pytest.raises(FaceTransferError, match="does not exist"):
        write_text_atomic(tmp_path / "no" / "x.txt", "a")
    with pytest.raises(FaceTransferError, match="--overwrite"):
        write_text_atomic(target, "x", overwrite=False)


def test_video_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    frames = np.repeat(rng.integers(0, 255, size=(6, 1, 32, 48, 1), dtype=np.uint8), 3, axis=1)
    frames = np.ascontiguousarray(np.moveaxis(frames[:, 0], -1, -1).repeat(3, axis=-1))
    p = write_video(tmp_path / "v.mp4", frames, 10)
    info = video_info(p)
    assert info.size == (48, 32) and info.n_frames == 6 and info.fps == pytest.approx(10)
    back, fps = read_video(p)
    assert back.shape == (6, 32, 48, 3)
    with pytest.raises(VideoError, match="does not exist"):
        video_info(tmp_path / "none.mp4")
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 10)
    with pytest.raises(VideoError):
        read_video(tmp_path / "junk.mp4")


@pytest.mark.parametrize("spill", [False, True])
@pytest.mark.parametrize("count", [2, 6, 40, 10 ** 12])
def test_read_video_does_not_trust_the_containers_frame_count(tmp_path, monkeypatch, count,
                                                               spill):
    """``read_video`` decodes into an array sized by the container's count: a count that is
    short (grown) or long (cut) gives the same frames as decoding one by one, in memory or
    (``spill``: past the frame budget) in a file."""
    import facetransfer.io.video_read as v
    from facetransfer.io.video import VideoInfo, iter_frames

    if spill:
        (tmp_path / "frames").mkdir()
        monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path / "frames"))
        monkeypatch.setenv("FACETRANSFER_FRAME_MEMORY", "0")

    rng = np.random.default_rng(2)
    frames = rng.integers(0, 255, size=(9, 16, 24, 3), dtype=np.uint8)
    p = write_video(tmp_path / "v.mp4", frames, 10)
    each = np.stack(list(iter_frames(p)))
    real = v.video_info(p)
    monkeypatch.setattr(v, "video_info", lambda path: VideoInfo(Path(path), real.fps, count,
                                                                real.size))
    for kw, want in (({}, each), ({"start": 3}, each[3:]), ({"max_frames": 4}, each[:4]),
                     ({"start": 2, "stop": 8}, each[2:8])):
        back, _ = read_video(p, **kw)
        np.testing.assert_array_equal(back, want)
        assert isinstance(back, np.memmap) == spill


def test_cli_bad_input_is_one_line_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "facetransfer.cli.main", "model", "info",
                        str(tmp_path / "nope.npz")], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    lines = [l for l in r.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and "nope.npz" in lines[0] and "Traceback" not in r.stderr


def test_write_image_and_save_figure_are_atomic(tmp_path):
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure, write_image

    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0] = 200                                   # red
    p = write_image(tmp_path / "a.png", rgb)
    np.testing.assert_array_equal(cv2.imread(str(p))[..., ::-1], rgb)
    with pytest.raises(FaceTransferError, match="cannot write image"):
        write_image(tmp_path / "b.unknown-format", rgb)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["a.png"]   # no temporary left
    fig = plt.figure()
    q = save_figure(fig, tmp_path / "f.png", dpi=20)
    assert q.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not plt.fignum_exists(fig.number)


def test_read_npz_maps_large_stored_members_and_reads_the_rest(tmp_path):
    """``mmap_min_bytes``: stored members at least that big are read-only maps of the file with
    the same values; compressed and small members are read as before; a truncated archive is
    one clear error."""
    from facetransfer.errors import ModelFileError
    from facetransfer.io.npz import read_npz

    rng = np.random.default_rng(0)
    big = rng.normal(size=(300, 7, 5))
    fort = np.asfortranarray(rng.normal(size=(40, 30)))
    small = np.arange(6, dtype=np.int32)
    p = tmp_path / "a.npz"
    np.savez(p, big=big, fort=fort, small=small)
    d = read_npz(p, "model file", ModelFileError, mmap_min_bytes=1000)
    assert np.array_equal(d["big"], big) and np.array_equal(d["fort"], fort)
    assert np.array_equal(d["small"], small) and d["small"].flags.writeable
    assert not d["big"].flags.writeable and isinstance(d["big"].base, np.memmap)
    assert type(d["big"]) is np.ndarray and d["fort"].flags.f_contiguous
    pc = tmp_path / "c.npz"
    np.savez_compressed(pc, big=big)
    dc = read_npz(pc, "model file", ModelFileError, mmap_min_bytes=1000)
    assert np.array_equal(dc["big"], big) and dc["big"].flags.writeable
    pt = tmp_path / "t.npz"
    pt.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(ModelFileError, match="t.npz"):
        read_npz(pt, "model file", ModelFileError, mmap_min_bytes=1000)


def test_prefetch_hands_out_what_read_video_gives(tmp_path, monkeypatch):
    """Background reads are handed out once, cut to the frames asked for; a read they do not
    cover (more frames than decoded before the clip's end, another file, a second request)
    is decoded on the spot; a damaged file raises when its frames are asked for."""
    import facetransfer.io.prefetch as pf
    import facetransfer.io.video as v

    rng = np.random.default_rng(3)
    a = write_video(tmp_path / "a.mp4", rng.integers(0, 255, (9, 16, 24, 3), np.uint8), 10)
    b = write_video(tmp_path / "b.mp4", rng.integers(0, 255, (5, 16, 24, 3), np.uint8), 25)
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 10)
    whole = {p: read_video(p)[0] for p in (a, b)}
    direct = []
    real = v.read_video
    pre = pf.Prefetch([(a, 6), (b, 50), (tmp_path / "junk.mp4", None)])
    pre2 = pf.Prefetch([(a, 6)])
    monkeypatch.setattr(v, "read_video", lambda p, **k: direct.append(Path(p).name) or real(p, **k))
    fr, fps = pre.read_video(tmp_path / "." / "a.mp4", max_frames=4)      # same file, cut
    np.testing.assert_array_equal(fr, whole[a][:4])
    assert fps == pytest.approx(10) and direct == []
    np.testing.assert_array_equal(pre.read_video(b)[0], whole[b])          # ended early: all
    np.testing.assert_array_equal(pre.read_video(a, max_frames=8)[0], whole[a][:8])  # again
    assert direct == ["a.mp4"]
    with pytest.raises(VideoError, match="junk.mp4"):
        pre.read_video(tmp_path / "junk.mp4")
    np.testing.assert_array_equal(pre2.read_video(a, max_frames=7)[0], whole[a][:7])  # > 6
    assert direct == ["a.mp4", "a.mp4"]


def test_frames_to_cover_another_rate(tmp_path):
    from facetransfer.io.prefetch import frames_covering, frames_to_cover

    assert frames_covering(300, 30.0, 30.0) == 301            # one beyond the last time
    assert frames_covering(300, 30.0, 25.0) == 251            # 299 / 30 s at 25 fps: 249.2
    assert frames_covering(1, 30.0, 25.0) == 2
    rng = np.random.default_rng(4)
    t = write_video(tmp_path / "t.mp4", rng.integers(0, 255, (12, 16, 24, 3), np.uint8), 30)
    s = write_video(tmp_path / "s.mp4", rng.integers(0, 255, (4, 16, 24, 3), np.uint8), 15)
    assert frames_to_cover(t, s) == frames_covering(12, 30.0, 15.0) + 8 == 15
    assert frames_to_cover(t, s, max_frames=5) == frames_covering(5, 30.0, 15.0) + 8 == 12
