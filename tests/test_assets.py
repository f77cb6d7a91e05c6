"""facetransfer.assets: registry, mirror, cache, download (file:// URLs, no network), checksums."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from facetransfer import assets
from facetransfer.assets import Asset, AssetFile
from facetransfer.errors import AssetError


@pytest.fixture
def env(tmp_path, monkeypatch):
    """Empty cache in tmp, no mirror, a fake two-file asset served from file:// URLs."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("FACETRANSFER_DATA_DIR", raising=False)
    monkeypatch.delenv("FACETRANSFER_OFFLINE", raising=False)
    src = tmp_path / "upstream"
    src.mkdir()
    files = {}
    for name, data in (("a.txt", b"hello asset\n"), ("sub/b.bin", bytes(range(256)) * 10)):
        p = src / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
        files[name] = AssetFile(name, p.as_uri(), hashlib.sha256(data).hexdigest())
    fake = Asset("fake", tuple(files.values()), "fake-mirror", "MIT", "test asset")
    single = Asset("fake1", (files["a.txt"],), "one/a.txt", "MIT", single_file=True)
    monkeypatch.setitem(assets.REGISTRY, "fake", fake)
    monkeypatch.setitem(assets.REGISTRY, "fake1", single)
    assets._clear_verified()
    yield {"src": src, "files": files, "tmp": tmp_path, "monkeypatch": monkeypatch}
    assets._clear_verified()


def test_registry_pins_every_needed_ict_file():
    ict = assets.REGISTRY["ict-facekit"]
    rel = {f.relpath for f in ict.files}
    need = {"generic_neutral_mesh.obj", "vertex_indices.json", "jawOpen.obj", "mouthSmile_L.obj"}
    need |= {f"identity{i:03d}.obj" for i in range(100)}
    assert need <= rel
    for f in ict.files:
        assert f.url.startswith(f"https://raw.githubusercontent.com/ICT-VGL/ICT-FaceKit/{assets.ICT_COMMIT}/")
        assert len(f.sha256) == 64 and int(f.sha256, 16) >= 0
    assert ict.licence == "MIT"
    lm = assets.REGISTRY["face_landmarker"].files[0]
    assert lm.sha256 == "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
    lps = assets.REGISTRY["lee-perry-smith"]
    assert {f.relpath for f in lps.files} == {"LeePerrySmith.glb", "Map-COL.jpg"}
    assert "Lee Perry-Smith" in lps.credit and lps.licence == "CC-BY-3.0"


def test_cache_dir_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert assets.cache_dir() == tmp_path / "x" / "facetransfer"
    assert assets.cache_dir().is_dir()


def test_data_dir_unset_is_none(monkeypatch):
    monkeypatch.delenv("FACETRANSFER_DATA_DIR", raising=False)
    assert assets.data_dir() is None
    monkeypatch.setenv("FACETRANSFER_DATA_DIR", "/some/where")
    assert assets.data_dir() == Path("/some/where")


def test_download_verifies_and_caches(env):
    p = assets.asset_path("fake")
    assert p == env["tmp"] / "cache" / "facetransfer" / "assets" / "fake"
    assert (p / "a.txt").read_bytes() == b"hello asset\n"
    assert (p / "sub" / "b.bin").read_bytes() == bytes(range(256)) * 10
    # second call: no download (the source is gone) and no re-hash of known files
    for f in env["src"].rglob("*"):
        if f.is_file():
            f.unlink()
    calls = []
    real = assets.sha256_file
    env["monkeypatch"].setattr(assets, "sha256_file", lambda q, **k: calls.append(q) or real(q))
    assert assets.asset_path("fake") == p
    assert calls == []


def test_single_file_asset_returns_file(env):
    p = assets.asset_path("fake1")
    assert p.name == "a.txt" and p.read_bytes() == b"hello asset\n"


def test_corrupt_download_is_rejected_and_removed(env):
    f = env["files"]["a.txt"]
    bad = Asset("bad", (AssetFile("a.txt", f.url, "0" * 64),), "bad", "MIT", single_file=True)
    env["monkeypatch"].setitem(assets.REGISTRY, "bad", bad)
    with pytest.raises(AssetError, match="sha256") as ei:
        assets.asset_path("bad")
    assert "bad" in str(ei.value) and f.url in str(ei.value)
    folder = env["tmp"] / "cache" / "facetransfer" / "assets" / "bad"
    assert not any(folder.rglob("*.txt")) and not any(folder.rglob("*.part"))


def test_corrupt_cached_file_is_never_used(env):
    p = assets.asset_file("fake", "a.txt")
    p.write_bytes(b"tampered\n")
    assets._clear_verified()
    # upstream still there: the bad copy is moved aside and the file fetched again
    q = assets.asset_file("fake", "a.txt")
    assert q.read_bytes() == b"hello asset\n"
    assert (q.parent / "a.txt.corrupt").read_bytes() == b"tampered\n"
    # tampered again and upstream gone: an error, never the bad bytes
    q.write_bytes(b"tampered again\n")
    assets._clear_verified()
    (env["src"] / "a.txt").unlink()
    with pytest.raises(AssetError, match="cannot download"):
        assets.asset_file("fake", "a.txt")


def test_missing_offline_message_names_asset_url_and_mirror(env):
    env["monkeypatch"].setenv("FACETRANSFER_OFFLINE", "1")
    with pytest.raises(AssetError) as ei:
        assets.asset_path("fake1")
    msg = str(ei.value)
    assert "'fake1'" in msg and env["files"]["a.txt"].url in msg and "FACETRANSFER_DATA_DIR" in msg
    assert "\n" not in msg


def test_unreachable_url_is_one_clear_error(env):
    gone = Asset("gone", (AssetFile("x.bin", (env["tmp"] / "nope.bin").as_uri(), "0" * 64),),
                 "gone", "MIT", single_file=True)
    env["monkeypatch"].setitem(assets.REGISTRY, "gone", gone)
    with pytest.raises(AssetError, match="'gone': cannot download .*FACETRANSFER_DATA_DIR"):
        assets.asset_path("gone")


def test_mirror_is_used_and_checked(env):
    mirror = env["tmp"] / "mirror"
    (mirror / "fake-mirror" / "sub").mkdir(parents=True)
    (mirror / "fake-mirror" / "a.txt").write_bytes(b"hello asset\n")
    (mirror / "fake-mirror" / "sub" / "b.bin").write_bytes(bytes(range(256)) * 10)
    env["monkeypatch"].setenv("FACETRANSFER_DATA_DIR", str(mirror))
    env["monkeypatch"].setenv("FACETRANSFER_OFFLINE", "1")
    assert assets.asset_path("fake") == mirror / "fake-mirror"
    assert assets.asset_file("fake", "sub/b.bin") == mirror / "fake-mirror" / "sub" / "b.bin"
    (mirror / "fake-mirror" / "a.txt").write_bytes(b"HELLO asset\n")  # same size, new mtime
    assets._clear_verified()
    with pytest.raises(AssetError, match="mirror file .*a.txt fails its sha256"):
        assets.asset_file("fake", "a.txt")


def test_unknown_asset_and_file(env):
    with pytest.raises(AssetError, match="unknown asset 'nope'"):
        assets.asset_path("nope")
    with pytest.raises(AssetError, match="no registered file"):
        assets.asset_file("fake", "c.txt")
    with pytest.raises(AssetError, match="name one"):
        assets.asset_file("fake")


def test_real_mirror_assets(data_dir, monkeypatch):
    monkeypatch.setenv("FACETRANSFER_DATA_DIR", str(data_dir))
    lm = assets.asset_path("face_landmarker")
    assert lm == data_dir / "mediapipe" / "face_landmarker.task"
    lps = assets.asset_path("lee-perry-smith")
    assert (lps / "LeePerrySmith.glb").is_file() and (lps / "Map-COL.jpg").is_file()
    vi = assets.asset_file("ict-facekit", "vertex_indices.json")
    assert len(json.loads(vi.read_text())["idx_to_landmark_verts"]) == 68


def test_download_progress_callback(env):
    seen = []
    p = assets.asset_file("fake", "sub/b.bin", progress=lambda done, total: seen.append((done, total)))
    assert p.stat().st_size == 2560
    assert seen and seen[-1][0] == 2560 and all(t in (0, 2560) for _, t in seen)


def test_incomplete_mirror_folder_is_completed_in_cache(env):
    mirror = env["tmp"] / "mirror"
    (mirror / "fake-mirror").mkdir(parents=True)
    (mirror / "fake-mirror" / "a.txt").write_bytes(b"hello asset\n")  # sub/b.bin missing
    env["monkeypatch"].setenv("FACETRANSFER_DATA_DIR", str(mirror))
    p = assets.asset_path("fake")
    assert p == env["tmp"] / "cache" / "facetransfer" / "assets" / "fake"
    assert (p / "a.txt").read_bytes() == b"hello asset\n"  # copied from the mirror
    assert (p / "sub" / "b.bin").read_bytes() == bytes(range(256)) * 10  # downloaded
    (p / "sub" / "b.bin").unlink()
    env["monkeypatch"].setenv("FACETRANSFER_OFFLINE", "1")
    with pytest.raises(AssetError, match=r"put the file at .*fake-mirror/sub/b.bin"):
        assets.asset_path("fake")
