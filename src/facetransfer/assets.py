"""External assets: where each comes from (pinned URL), its sha256 and licence; download and cache.

Nothing here is shipped in the repository. An asset is found, in order, in

1. the offline mirror ``$FACETRANSFER_DATA_DIR`` laid out like the project's shared data folder
   (``ict-facekit/FaceXModel/…``, ``mediapipe/face_landmarker.task``, ``lee-perry-smith/…``);
2. the user cache ``$XDG_CACHE_HOME/facetransfer/assets`` (default ``~/.cache/facetransfer``);
3. its pinned upstream URL, downloaded into the cache with a progress bar.

Every file is checked against its registered sha256 before it is used; a file that fails is never
returned (a downloaded or cached one is removed, a mirror one is reported). Checks are remembered per
process by ``(path, size, mtime)``, and files are checked lazily, only when asked for, so reading
three files of a 160-file asset hashes three files.

Examples
--------
>>> from facetransfer.assets import asset_path, asset_file   # doctest: +SKIP
>>> asset_path("face_landmarker")                             # doctest: +SKIP
PosixPath('/…/mediapipe/face_landmarker.task')
>>> asset_file("ict-facekit", "generic_neutral_mesh.obj")      # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import threading
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Callable, Mapping

from .errors import AssetError
from .io.atomic import atomic_path

log = logging.getLogger(__name__)

__all__ = [
    "Asset",
    "AssetFile",
    "REGISTRY",
    "asset_path",
    "asset_file",
    "cache_dir",
    "data_dir",
    "fetch",
    "sha256_file",
    "set_download_progress",
    "verify_file",
]

#: Environment variable naming the offline mirror folder.
DATA_DIR_ENV = "FACETRANSFER_DATA_DIR"
#: Set to 1 to forbid downloads (a missing asset is then an error at once).
OFFLINE_ENV = "FACETRANSFER_OFFLINE"

ICT_COMMIT = "da5f95a607f5e6b37755b38d3385d7f2853732e5"
THREEJS_COMMIT = "5ae96fa93595c324f2aba52dd40c98aa9da1e8f0"
MEDIAPIPE_COMMIT = "85c0cdc7d70653888903c88df45962b764296342"

_MIRROR_HINT = (f"set {DATA_DIR_ENV} to an offline mirror folder laid out like the project's "
                "shared data (see README)")


@dataclass(frozen=True)
class AssetFile:
    """One file of an asset.

    Attributes
    ----------
    relpath : str
        Path inside the asset folder (``"jawOpen.obj"``); for single-file assets, the file name.
    url : str
        Pinned download URL.
    sha256 : str
        Hex digest the file must have.
    """

    relpath: str
    url: str
    sha256: str


@dataclass(frozen=True)
class Asset:
    """A registered external asset.

    Attributes
    ----------
    name : str
        Registry key.
    files : tuple of AssetFile
    mirror : str
        Location inside the mirror folder: the folder holding the files (folder assets) or the
        file itself (single-file assets), POSIX-style relative path.
    licence : str
        SPDX-like licence name.
    credit : str
        Attribution to show wherever the asset (or anything derived from it) is shown.
    single_file : bool
        True when the asset is one file and :func:`asset_path` returns that file.
    source : str
        Human-readable upstream location (repository folder at the pinned commit).
    """

    name: str
    files: tuple[AssetFile, ...]
    mirror: str
    licence: str
    credit: str = ""
    single_file: bool = False
    source: str = ""

    def file(self, relpath: str) -> AssetFile:
        for f in self.files:
            if f.relpath == relpath:
                return f
        raise AssetError(f"asset {self.name!r} has no registered file {relpath!r}")


def _ict_asset() -> Asset:
    table = json.loads(resources.files("facetransfer.data").joinpath(
        "ict_facekit_sha256.json").read_text())
    if table.get("commit") != ICT_COMMIT:
        raise AssetError("ict_facekit_sha256.json is for another ICT-FaceKit commit")
    base = f"https://raw.githubusercontent.com/ICT-VGL/ICT-FaceKit/{ICT_COMMIT}/"
    files = []
    for path, digest in sorted(table["sha256"].items()):
        rel = path.split("/", 1)[1] if path.startswith("FaceXModel/") else "../" + path
        if rel.startswith("../"):
            continue  # LICENSE sits beside FaceXModel/; recorded but not part of the folder asset
        files.append(AssetFile(rel, base + path, digest))
    return Asset("ict-facekit", tuple(files), "ict-facekit/FaceXModel", "MIT",
                 "ICT-FaceKit, (c) 2020 USC Institute for Creative Technologies, MIT licence",
                 source=f"https://github.com/ICT-VGL/ICT-FaceKit/tree/{ICT_COMMIT}/FaceXModel")


def _registry() -> dict[str, Asset]:
    lps = f"https://raw.githubusercontent.com/mrdoob/three.js/{THREEJS_COMMIT}/examples/models/gltf/LeePerrySmith/"
    mp = (f"https://raw.githubusercontent.com/google-ai-edge/mediapipe/{MEDIAPIPE_COMMIT}/"
          "mediapipe/modules/face_geometry/data/")
    assets = [
        _ict_asset(),
        Asset("face_landmarker", (AssetFile(
            "face_landmarker.task",
            "https://storage.googleapis.com/mediapipe-models/face_landmarker/face_landmarker/"
            "float16/1/face_landmarker.task",
            "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"),),
            "mediapipe/face_landmarker.task", "Apache-2.0",
            "MediaPipe Face Landmarker (Google), Apache-2.0", single_file=True),
        Asset("lee-perry-smith", (
            AssetFile("LeePerrySmith.glb", lps + "LeePerrySmith.glb",
                      "402b8a8ac9f03232e6d64b5962929703a069daf99d3c49ac8eb0e48bedc9c576"),
            AssetFile("Map-COL.jpg", lps + "Map-COL.jpg",
                      "e976d73b31407f8d0967412bf468019ed26a5d5a32cf5811aabff7e816458a65"),
        ), "lee-perry-smith", "CC-BY-3.0",
            "Infinite, 3D Head Scan by Lee Perry-Smith (Infinite Realities), CC-BY 3.0",
            source=f"https://github.com/mrdoob/three.js/tree/{THREEJS_COMMIT}/examples/models/gltf/LeePerrySmith"),
        Asset("canonical_face_model", (AssetFile(
            "canonical_face_model.obj", mp + "canonical_face_model.obj",
            "8bac80443397e113f41a8b565ea72c59390bc031d9defab289dba7bc0c54e618"),),
            "mediapipe/canonical_face_model.obj", "Apache-2.0",
            "MediaPipe canonical face model (Google), Apache-2.0", single_file=True),
    ]
    return {a.name: a for a in assets}


#: Every known asset by name. Tests may add entries (e.g. with ``file://`` URLs).
REGISTRY: dict[str, Asset] = _registry()

# (realpath, size, mtime_ns) -> sha256 hex, for files already hashed in this process
_VERIFIED: dict[tuple[str, int, int], str] = {}
_LOCK = threading.Lock()
# progress shown for downloads when the caller passes none (the CLI turns it on)
_DEFAULT_PROGRESS: bool = False
_ANNOUNCED: set[str] = set()


def set_download_progress(enabled: bool) -> None:
    """Show (or hide) a tqdm progress bar for downloads made without an explicit ``progress``.

    Library code never prints; the command-line interface calls this so that a first-use
    download of a large asset is visible.
    """
    global _DEFAULT_PROGRESS
    _DEFAULT_PROGRESS = bool(enabled)


def data_dir() -> Path | None:
    """The offline mirror folder from ``$FACETRANSFER_DATA_DIR``, or None when unset or empty."""
    v = os.environ.get(DATA_DIR_ENV, "").strip()
    return Path(v).expanduser() if v else None


def switched_off(variable: str) -> bool:
    """Whether the environment variable ``variable`` says ``off`` (or ``0``, ``no``,
    ``false``): the switches of the caches (``FACETRANSFER_TRACK_CACHE``,
    ``FACETRANSFER_RENDER_CACHE``)."""
    return os.environ.get(variable, "").strip().lower() in ("off", "0", "no", "false")


def cache_dir() -> Path:
    """User cache folder ``$XDG_CACHE_HOME/facetransfer`` (default ``~/.cache/facetransfer``).

    Created on first call.
    """
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    root = Path(base).expanduser() if base else Path.home() / ".cache"
    d = root / "facetransfer"
    d.mkdir(parents=True, exist_ok=True)
    return d


def others_beside(path: Path, pattern: str) -> list[Path]:
    """The files in ``path``'s folder whose names match ``pattern`` (a glob), ``path`` itself
    left out, newest first: a cached file's versions under other keys (the default model's
    other recipes, a data set's other builders). OSError where the folder cannot be read."""
    others = [p for p in path.parent.glob(pattern) if p != path and p.is_file()]
    return sorted(others, key=lambda p: p.stat().st_mtime, reverse=True)


def prune_beside(path: Path, pattern: str, keep: int, what: str, *,
                 also: Callable[[Path], Path] | None = None) -> None:
    """Remove :func:`others_beside` ``path`` but the ``keep`` newest (and ``also`` of each: a
    record kept beside it), each logged as ``what``; a folder that cannot be pruned (another
    process's pruning, a read-only cache) is left, with a warning."""
    try:
        for p in others_beside(path, pattern)[keep:]:
            p.unlink(missing_ok=True)
            if also is not None:
                also(p).unlink(missing_ok=True)
            log.info("removed %s (%s)", p, what)
    except OSError as exc:
        log.warning("could not prune the files beside %s (%s)", path, exc)


def _get(name: str) -> Asset:
    try:
        return REGISTRY[name]
    except KeyError:
        raise AssetError(f"unknown asset {name!r}; known: {', '.join(sorted(REGISTRY))}") from None


def sha256_file(path: str | os.PathLike, *, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            b = fh.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def _key(path: Path) -> tuple[str, int, int]:
    st = path.stat()
    return (str(path.resolve()), st.st_size, st.st_mtime_ns)


def verify_file(path: str | os.PathLike, sha256: str) -> bool:
    """True when ``path`` has digest ``sha256``; remembered per process by (path, size, mtime)."""
    p = Path(path)
    key = _key(p)
    with _LOCK:
        known = _VERIFIED.get(key)
    if known is None:
        known = sha256_file(p)
        with _LOCK:
            _VERIFIED[key] = known
    return known == sha256.lower()


def _cache_location(asset: Asset, f: AssetFile) -> Path:
    return cache_dir() / "assets" / asset.name / f.relpath


def _mirror_location(asset: Asset, f: AssetFile) -> Path | None:
    root = data_dir()
    if root is None:
        return None
    base = root / Path(asset.mirror)
    return base if asset.single_file else base / f.relpath


def fetch(url: str, dest: str | os.PathLike, sha256: str, *, name: str = "",
          progress: bool | Callable[[int, int], None] = False, timeout: float = 60.0,
          hint: str = _MIRROR_HINT) -> Path:
    """Download ``url`` to ``dest`` (atomically) and check its sha256.

    Parameters
    ----------
    url : str
        ``https://`` or ``file://`` URL.
    dest : path-like
        Final location; its folder is created.
    sha256 : str
        Expected hex digest. A download that does not match is deleted and never used.
    name : str
        Asset name for messages.
    progress : bool or callable
        True shows a tqdm bar; a callable gets ``(bytes_done, bytes_total)``.
    hint : str
        How to provide the file otherwise, appended to error messages.

    Raises
    ------
    AssetError
        Offline, HTTP error, or checksum mismatch.
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    label = name or dest.name
    if os.environ.get(OFFLINE_ENV, "").strip() not in ("", "0"):
        raise AssetError(f"asset {label!r} is not available offline ({OFFLINE_ENV} is set); "
                         f"it is downloaded from {url}; {hint}")
    import urllib.error  # here: every command imports this module, few download
    import urllib.request

    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.part")
    h = hashlib.sha256()
    bar = None
    try:
        with urllib.request.urlopen(url, timeout=timeout) as resp, open(tmp, "wb") as out:
            total = int(resp.headers.get("Content-Length") or 0)
            if progress is True:
                from tqdm import tqdm

                bar = tqdm(total=total or None, unit="B", unit_scale=True,  # a terminal's only
                           desc=f"{label}: {dest.name}", leave=False, disable=None)
            done = 0
            while True:
                b = resp.read(1 << 16)
                if not b:
                    break
                out.write(b)
                h.update(b)
                done += len(b)
                if bar is not None:
                    bar.update(len(b))
                elif callable(progress):
                    progress(done, total)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        tmp.unlink(missing_ok=True)
        reason = getattr(exc, "reason", None) or exc
        raise AssetError(f"asset {label!r}: cannot download {url} ({reason}); {hint}") from None
    finally:
        if bar is not None:
            bar.close()
    if h.hexdigest() != sha256.lower():
        tmp.unlink(missing_ok=True)
        raise AssetError(f"asset {label!r}: download of {url} has sha256 {h.hexdigest()}, "
                         f"expected {sha256}; the file was discarded")
    os.replace(tmp, dest)
    with _LOCK:
        _VERIFIED[_key(dest)] = sha256.lower()
    return dest


def _hint(mirror: Path | None) -> str:
    if mirror is None:
        return _MIRROR_HINT
    return f"or put the file at {mirror} ({DATA_DIR_ENV}={data_dir()})"


def _resolve_file(asset: Asset, f: AssetFile, *, download: bool,
                  progress: bool | Callable[[int, int], None] | None,
                  into_cache: bool = False) -> Path:
    """Verified path of one file: mirror, else cache, else download into the cache.

    With ``into_cache`` the result is always in the cache (a mirror copy is copied there), so
    that a folder asset can be assembled in one place.
    """
    mirror = _mirror_location(asset, f)
    if not into_cache and mirror is not None and mirror.is_file():
        if not verify_file(mirror, f.sha256):
            raise AssetError(f"asset {asset.name!r}: mirror file {mirror} fails its sha256 check "
                             f"(expected {f.sha256}); replace it with the file from {f.url}")
        return mirror
    cached = _cache_location(asset, f)
    if cached.is_file():
        if verify_file(cached, f.sha256):
            return cached
        bad = cached.with_name(cached.name + ".corrupt")
        os.replace(cached, bad)
        log.warning("asset %s: cached %s failed its sha256 check; moved to %s", asset.name,
                    cached, bad)
    if into_cache and mirror is not None and mirror.is_file() and verify_file(mirror, f.sha256):
        cached.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cached) as tmp:
            shutil.copyfile(mirror, tmp)
        return cached
    if not download:
        where = f"{mirror}" if mirror is not None else f"{DATA_DIR_ENV} (unset)"
        raise AssetError(f"asset {asset.name!r} file {f.relpath!r} is missing (looked in {where} "
                         f"and {cached}); download it from {f.url} {_hint(mirror)}")
    if asset.name not in _ANNOUNCED:
        _ANNOUNCED.add(asset.name)
        log.warning("asset %s is not in %s or the cache; downloading it from %s into %s",
                    asset.name, DATA_DIR_ENV, asset.source or f.url, cache_dir() / "assets")
    log.info("downloading %s from %s", asset.name, f.url)
    if progress is None:
        progress = _DEFAULT_PROGRESS
    return fetch(f.url, cached, f.sha256, name=asset.name, progress=progress, hint=_hint(mirror))


def asset_file(name: str, relpath: str | None = None, *, download: bool = True,
               progress: bool | Callable[[int, int], None] | None = None) -> Path:
    """Path of one verified file of an asset (fetched if needed).

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"ict-facekit"``.
    relpath : str, optional
        File inside the asset (e.g. ``"jawOpen.obj"``); optional for single-file assets.
    download : bool
        Allow downloading into the cache when neither the mirror nor the cache has it.
    progress : bool or callable, optional
        Download progress: True for a tqdm bar, a callable for ``(done, total)`` bytes; default
        as set by :func:`set_download_progress` (off).

    Raises
    ------
    AssetError
        Unknown asset or file, missing offline, or checksum failure.
    """
    asset = _get(name)
    if relpath is None:
        if len(asset.files) != 1:
            raise AssetError(f"asset {name!r} has {len(asset.files)} files; name one")
        f = asset.files[0]
    else:
        f = asset.file(relpath)
    return _resolve_file(asset, f, download=download, progress=progress)


def asset_path(name: str, *, download: bool = True,
               progress: bool | Callable[[int, int], None] | None = None) -> Path:
    """Location of an asset: the file (single-file assets) or the folder holding all its files.

    A folder asset is complete and verified when this returns: in the mirror when the mirror has
    all of its files, otherwise in the cache (downloading what is missing). Files are hashed once
    per process.

    Raises
    ------
    AssetError
        Unknown asset, missing offline (the message names the asset, its URL and the mirror
        variable), or a file failing its sha256 check.
    """
    asset = _get(name)
    if asset.single_file:
        return asset_file(name, download=download, progress=progress)
    root = data_dir()
    mirror = root / Path(asset.mirror) if root is not None else None
    if mirror is not None and all((mirror / f.relpath).is_file() for f in asset.files):
        for f in asset.files:
            _resolve_file(asset, f, download=False, progress=False)
        return mirror
    for f in asset.files:  # assemble the complete folder in the cache
        _resolve_file(asset, f, download=download, progress=progress, into_cache=True)
    return cache_dir() / "assets" / asset.name


def describe(name: str) -> Mapping[str, str]:
    """Licence, credit and first URL of an asset, for provenance records."""
    a = _get(name)
    return {"asset": a.name, "licence": a.licence, "credit": a.credit,
            "source": a.source or (a.files[0].url if a.files else "")}


def _clear_verified() -> None:
    """Forget remembered checks (for tests)."""
    with _LOCK:
        _VERIFIED.clear()
