"""Fault injection on outputs (issue 16): a read-only folder, a full disk, SIGKILL in the middle of
a write, two concurrent writers and a planted symlink. Each asserts that the old output survives
(or the new one is complete), nothing else in the folder or outside it is touched, and no
temporary file remains.

Root ignores permission bits, so the read-only folder is simulated by making the exclusive create
fail with ``PermissionError`` (always), and is also a real read-only tmpfs mount when the tests run
as root where ``mount`` works (then the full disk is a real 64 KiB tmpfs too).
"""

from __future__ import annotations

import errno
import hashlib
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from facetransfer.errors import OutputError
from facetransfer.io import atomic
from facetransfer.io.atomic import atomic_path, remove_stale_temps, write_bytes_atomic

OLD = b"old good output\n"
SRC = str(Path(__file__).resolve().parents[1] / "src")


def snapshot(*folders: Path) -> dict:
    """Every entry of ``folders`` (recursively): kind and content hash (links: their target)."""
    out = {}
    for folder in folders:
        for p in sorted(folder.rglob("*")):
            if p.is_symlink():
                out[str(p)] = ("link", os.readlink(p))
            elif p.is_file():
                out[str(p)] = ("file", hashlib.sha256(p.read_bytes()).hexdigest())
            else:
                out[str(p)] = ("dir", None)
    return out


def temps(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


@pytest.fixture
def scene(tmp_path):
    """``out/`` holding an old output and a neighbour, and ``outside/`` holding a victim."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (out / "result.npz").write_bytes(OLD)
    (out / "neighbour.txt").write_text("keep me\n")
    (outside / "victim.txt").write_text("precious\n")
    return out / "result.npz", outside


def assert_untouched(before: dict, target: Path, *, new: bytes | None = None) -> None:
    """Everything ``before`` recorded is as it was (``target`` holds ``new`` if given), nothing
    was added, no temporary file is left."""
    folders = {target.parent} | {Path(k).parent for k in before}
    after = {k: v for k, v in snapshot(*sorted(folders)).items()
             if k in before or Path(k).parent in folders}
    expect = dict(before)
    key = str(target)
    if new is not None:
        expect[key] = ("file", hashlib.sha256(new).hexdigest())
    assert after == expect
    assert temps(target.parent) == []


# ------------------------------------------------------------------------------ read-only folder
def test_read_only_folder_simulated(scene, monkeypatch):
    target, outside = scene
    before = snapshot(target.parent, outside)

    def refuse(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(target.parent / ".x"))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    with pytest.raises(OutputError, match=r"cannot write .*result\.npz: permission denied"):
        write_bytes_atomic(target, b"new")
    assert_untouched(before, target)


def test_read_only_folder_cli_is_one_line(scene, monkeypatch, capsys, tmp_path):
    from facetransfer.cli.main import main

    target, outside = scene
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    out = target.with_name("smooth.obj")
    out.write_bytes(OLD)
    before = snapshot(target.parent, outside)

    def refuse(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    assert main(["scan", "smooth", str(mesh), "--out", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"facetransfer scan smooth: error: cannot write {out}: permission denied (is the "
                   "folder read-only?)"]
    assert_untouched(before, out)


def _mount(path: Path, opts: str) -> bool:
    if os.geteuid() != 0:
        return False
    path.mkdir(exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)],
                       capture_output=True)
    return r.returncode == 0


@pytest.fixture
def tmpfs(tmp_path):
    mounted = []

    def make(name: str, opts: str) -> Path:
        p = tmp_path / name
        if not _mount(p, opts):
            pytest.skip("cannot mount a tmpfs here (needs root and mount)")
        mounted.append(p)
        return p

    yield make
    for p in mounted:
        subprocess.run(["umount", str(p)], check=False)


def test_read_only_folder_real_mount(tmpfs, tmp_path):
    d = tmpfs("ro", "size=64k")
    target = d / "result.npz"
    target.write_bytes(OLD)
    subprocess.run(["mount", "-o", "remount,ro", str(d)], check=True)
    before = snapshot(d)
    with pytest.raises(OutputError, match="read-only file system"):
        with atomic_path(target) as tmp:
            np.savez(tmp, a=np.zeros(10))
    assert_untouched(before, target)


# ------------------------------------------------------------------------------ full disk
def test_full_disk_patched_write(scene, monkeypatch):
    """The write fails half-way with ENOSPC: the old file survives, the temp is removed."""
    target, outside = scene
    before = snapshot(target.parent, outside)
    with pytest.raises(OutputError, match=r"cannot write .*result\.npz: no space left"):
        with atomic_path(target) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half a fi")
                raise OSError(errno.ENOSPC, "No space left on device")
    assert_untouched(before, target)


def test_full_disk_at_fsync(scene, monkeypatch):
    """Delayed allocation: the data were accepted but the flush to disk fails."""
    target, outside = scene
    before = snapshot(target.parent, outside)

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", full)
    with pytest.raises(OutputError, match="no space left"):
        write_bytes_atomic(target, b"new content")
    assert_untouched(before, target)


def test_full_disk_real_tmpfs_cli(tmpfs, tmp_path, capsys):
    """``model synth --overwrite`` onto a full 64 KiB tmpfs: exit 2, one line, old mesh kept."""
    from facetransfer.cli.main import main
    from facetransfer.datasets import FaceDataset
    from facetransfer.model import build_model

    rng = np.random.default_rng(0)
    n = 4000   # a 4000-vertex mesh does not fit in what is left
    v = rng.normal(size=(2, 2, n, 3))
    faces = np.stack([np.arange(n - 2), np.arange(1, n - 1), np.arange(2, n)], axis=1)
    ds = FaceDataset(v, np.ones((2, 2), bool), ("identity", "expression"),
                     (("a", "b"), ("n", "s")), faces, None, None, None, {})
    model = tmp_path / "m.npz"
    build_model(ds, {"identity": 2, "expression": 2}).save(model)
    d = tmpfs("full", "size=64k")
    target = d / "face.obj"
    target.write_bytes(OLD)
    (d / "filler").write_bytes(b"x" * 40000)
    before = snapshot(d)
    assert main(["model", "synth", str(model), "--out", str(target), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"facetransfer model synth: error: cannot write {target}: no space left on the "
                   "device"]
    assert_untouched(before, target)


# ------------------------------------------------------------------------------ SIGKILL
WRITER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {src!r})
    from facetransfer.io.atomic import atomic_path
    with atomic_path({target!r}) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(b"partial data " * 1000)
            fh.flush()
            print(tmp, flush=True)
            time.sleep(60)
""")


def _start_writer(target: Path) -> tuple[subprocess.Popen, Path]:
    proc = subprocess.Popen([sys.executable, "-c", WRITER.format(src=SRC, target=str(target))],
                            stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline().strip()
    assert line, "the writer did not start"
    return proc, Path(line)


def test_sigkill_mid_write_then_next_run_cleans_up(scene):
    target, outside = scene
    before = snapshot(target.parent, outside)
    proc, tmp = _start_writer(target)
    live = remove_stale_temps(target)          # a live writer's temp is never removed
    assert live == [] and tmp.is_file()
    proc.kill()                                # SIGKILL: no clean-up runs
    proc.wait(timeout=10)
    assert target.read_bytes() == OLD and tmp.is_file() and temps(target.parent) == [tmp.name]
    write_bytes_atomic(target, b"second run")   # the next run of the same output
    assert_untouched(before, target, new=b"second run")


def test_stale_temps_of_other_outputs_are_left_alone(scene):
    target, _ = scene
    other = target.with_name("other.npz")
    proc, tmp = _start_writer(other)
    proc.kill()
    proc.wait(timeout=10)
    write_bytes_atomic(target, b"new")
    assert tmp.is_file()                       # not ours: left for other.npz's next run
    write_bytes_atomic(other, b"x")
    assert not tmp.exists()


# ------------------------------------------------------------------------------ concurrency
def test_two_concurrent_writers(scene):
    """Both write at once: each has its own temp, the output is one complete version."""
    target, outside = scene
    before = snapshot(target.parent, outside)
    barrier = threading.Barrier(2)
    seen: list[Path] = []
    errors: list[BaseException] = []

    def writer(tag: bytes):
        try:
            with atomic_path(target) as tmp:
                seen.append(tmp)
                barrier.wait(timeout=10)       # both temps exist at the same time
                tmp.write_bytes(tag * 5000)
                barrier.wait(timeout=10)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    ts = [threading.Thread(target=writer, args=(t,)) for t in (b"A", b"B")]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert errors == [] and len(set(seen)) == 2
    final = target.read_bytes()
    assert final in (b"A" * 5000, b"B" * 5000)
    assert_untouched(before, target, new=final)


def test_concurrent_writers_without_overwrite_second_is_refused(tmp_path):
    target = tmp_path / "new.npz"
    barrier = threading.Barrier(2)
    results: dict[bytes, object] = {}

    def writer(tag: bytes):
        try:
            with atomic_path(target, overwrite=False) as tmp:
                barrier.wait(timeout=10)       # both passed the "does not exist" check
                tmp.write_bytes(tag)
                if tag == b"B":
                    time.sleep(0.2)            # B commits second
            results[tag] = "ok"
        except OutputError as exc:
            results[tag] = exc

    ts = [threading.Thread(target=writer, args=(t,)) for t in (b"A", b"B")]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert results[b"A"] == "ok" and isinstance(results[b"B"], OutputError)
    assert "exists" in str(results[b"B"]) and target.read_bytes() == b"A"
    assert temps(tmp_path) == []


# ------------------------------------------------------------------------------ symlinks
def test_planted_symlinks_are_never_followed(scene):
    target, outside = scene
    victim = outside / "victim.txt"
    for name in (".result.part.npz", ".result.npz.part", "..result.video.part.npz"):
        (target.parent / name).symlink_to(victim)
    # a planted link with the pid-form name of a dead writer is not a regular file: kept
    (target.parent / ".result.999999999-abc.part.npz").symlink_to(victim)
    before = snapshot(target.parent, outside)
    write_bytes_atomic(target, b"new")
    assert victim.read_text() == "precious\n"
    after = snapshot(target.parent, outside)
    before[str(target)] = ("file", hashlib.sha256(b"new").hexdigest())
    assert after == before


def test_temp_swapped_for_a_symlink_is_refused(scene):
    target, outside = scene
    victim = outside / "victim.txt"
    before = snapshot(target.parent, outside)
    with pytest.raises(OutputError, match="replaced"):
        with atomic_path(target) as tmp:
            tmp.unlink()
            tmp.symlink_to(victim)             # an attacker swaps the temp for a link
    assert victim.read_text() == "precious\n"
    assert_untouched(before, target)


def test_output_that_is_a_symlink_to_an_input_is_refused(scene, tmp_path):
    from facetransfer.io.atomic import check_output_path

    target, outside = scene
    link = target.with_name("alias.npz")
    link.symlink_to(target)
    with pytest.raises(OutputError, match="also an input"):
        check_output_path(link, inputs=[target])
    with pytest.raises(OutputError, match="also an input"):
        check_output_path(target.parent / "." / "result.npz", inputs=[str(target)])


def test_an_output_named_as_a_folder_is_refused(tmp_path):
    """``--out sub.npz/`` wrote a file ``sub.npz`` (the slash dropped): refused, nothing
    written."""
    from facetransfer.io.atomic import atomic_path, check_output_path

    for out in (f"{tmp_path}/sub.npz/", f"{tmp_path}/new/"):
        with pytest.raises(OutputError, match="ends in '/', a folder's name; give a file name"):
            check_output_path(out)
        with pytest.raises(OutputError, match="a folder's name"):
            with atomic_path(out):
                pass
    from facetransfer.io.video import check_video_output

    with pytest.raises(OutputError, match="a folder's name"):  # a Path made of it dropped it
        check_video_output(f"{tmp_path}/result.mp4/")
    assert list(tmp_path.iterdir()) == []
    assert check_output_path(tmp_path / "ok.npz") == tmp_path / "ok.npz"
