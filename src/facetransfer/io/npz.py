"""Reading ``.npz`` files so that any damage is one clear error naming the file.

``numpy.load`` answers a truncated, empty or foreign file with many exception types
(``zipfile.BadZipFile``, ``EOFError``, ``ValueError`` with numpy's ``allow_pickle`` hint, ``OSError``,
``KeyError``, ``zlib.error``…). :func:`read_npz` turns all of them into the caller's
:class:`~facetransfer.errors.FaceTransferError` subclass, with the path and what was expected.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError


def check_input_file(path: str | os.PathLike, what: str,
                     error: type[FaceTransferError] = FaceTransferError) -> Path:
    """``path`` as a Path if it is an existing regular file; else ``error`` saying what it is.

    Raises
    ------
    FaceTransferError (``error``)
        ``"{what} {path} does not exist"``, ``"... is a folder, not a file"`` or ``"... is empty"``.
    """
    p = Path(path)
    if p.is_dir():
        raise error(f"{what} {p} is a folder, not a file")
    if not p.is_file():
        raise error(f"{what} {p} does not exist")
    if p.stat().st_size == 0:
        raise error(f"{what} {p} is empty")
    return p


NOT_NPZ = "not an .npz archive"
#: Leading bytes of files a user may hand where an ``.npz`` is expected, and what they are.
_MAGIC = ((b"glTF", "a glTF binary (a .glb, as `facetransfer export` writes)"),
          (b"PXR-USDC", "a USD file (as `facetransfer export` writes)"),
          (b"#usda", "a USD file (as `facetransfer export` writes)"),
          (b"Timecode,", "a Live Link Face take (CSV)"),
          (b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"),
          (b"<!DOCTYPE html", "an HTML page (as `facetransfer view` writes)"),
          (b"{", "a JSON file"))


def content_kind(path: str | os.PathLike) -> str | None:
    """What the file ``path`` is by its first bytes, where it is not a zip archive (an
    ``.npz`` is one): one of :data:`_MAGIC`'s, a video (an ISO media ``ftyp`` box, Matroska,
    AVI), or ``"not an .npz archive"``; None for a zip archive (a damaged one too) or a file
    that cannot be read."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    if head.startswith(b"PK"):
        return None
    for magic, kind in _MAGIC:
        if head.lstrip(b"\xef\xbb\xbf").startswith(magic):
            return kind
    if head[4:8] == b"ftyp" or head.startswith((b"\x1a\x45\xdf\xa3", b"RIFF")):
        return "a video"
    return NOT_NPZ


def known_npz(p: Path, names) -> str | None:
    """What the .npz archive ``p`` of array ``names`` is when it is one of the other archives
    facetransfer or its data folder hold (synth-video's ground truth, MediaPipe's landmarks of
    a clip), else None."""
    names = set(names)
    if {"meta", "vertices2d", "landmark_indices"} <= names:
        return "a synthetic clip's ground truth (synth-video's CLIP.truth.npz)"
    if Path(p).name.endswith(".mediapipe478.npz") or names == {"landmarks", "note"}:
        return "MediaPipe's 478 landmarks of a clip (the data folder's reference)"
    return None


#: What :func:`archive_names` raises for a file that is no ``.npz`` archive nor ``.npy`` array
#: (``numpy.load``'s kinds of error: damaged, truncated, foreign).
NOT_ARCHIVE_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile)


def archive_names(path: str | os.PathLike) -> set[str] | None:
    """The member names of the ``.npz`` archive at ``path`` (as ``numpy.load`` names them,
    from the archive's directory: no array is read); None where the file is a single ``.npy``
    array (``numpy.load``'s other kind; mapped, not read). One of :data:`NOT_ARCHIVE_ERRORS`
    for a file of neither kind."""
    z = np.load(path, mmap_mode="r", allow_pickle=False)
    if not isinstance(z, np.lib.npyio.NpzFile):
        return None
    with z:
        return set(z.files)


def read_npz(path: str | os.PathLike, what: str,
             error: type[FaceTransferError] = FaceTransferError, *,
             mmap_min_bytes: int | None = None) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file, read eagerly (no pickles).

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be, for messages (``"track file"``).
    error : FaceTransferError subclass
        Raised for any problem.
    mmap_min_bytes : int, optional
        Map members of at least this size that are stored uncompressed (``numpy.savez``) from
        the file, read-only, instead of reading them (:func:`mapped_members`): pages are read
        when first touched and shared between processes. The zip's CRC is then not checked:
        for callers that verify the content themselves (a model file's sha256).

    Returns
    -------
    dict name -> ndarray

    Raises
    ------
    FaceTransferError (``error``)
        Missing, a folder, empty, truncated, damaged, or not an ``.npz`` file of plain arrays.
    """
    p = check_input_file(path, what, error)
    try:
        z = np.load(p, allow_pickle=False)
    except MemoryError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, EOFError, OSError, ValueError (pickle)…
        kind = content_kind(p)
        if kind == NOT_NPZ:
            raise error(f"{what} {p} is not a {what} ({kind})") from None
        if kind is not None:             # another kind of file altogether: said as such
            raise error(f"{what} {p} is not a {what}: it is {kind}") from None
        raise error(f"{what} {p} is truncated or not a {what} ({reason(exc)})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise error(f"{what} {p} is not a {what} (a single .npy array, not an .npz archive)")
    try:
        with z:
            mapped = {} if mmap_min_bytes is None else mapped_members(p, z, mmap_min_bytes)
            arrays = {k: mapped[k] if k in mapped else z[k] for k in z.files}
    except MemoryError:
        # a damaged header's shape (745 GiB of a 1 kB file) was said as "out of memory"
        over = oversized_members(p)
        if over:
            raise error(f"{what} {p} is damaged: member(s) {', '.join(over)} declare more data "
                        "than they hold") from None
        raise
    except Exception as exc:  # a damaged member: bad CRC, zlib.error, EOFError, pickle…
        raise error(f"{what} {p} is truncated or not a {what} ({reason(exc)})") from None
    raw = sorted(k for k, a in arrays.items() if not isinstance(a, np.ndarray))
    if raw:   # numpy hands a member without the .npy header over as its bytes, unread
        raise error(f"{what} {p} is damaged or not a {what}: member(s) {', '.join(raw)} "
                    "are not .npy arrays")
    return arrays


def oversized_members(path: Path) -> list[str]:
    """The members of the ``.npz`` archive at ``path`` whose ``.npy`` header declares more
    bytes of data than the member holds (a damaged header), by name."""
    import zipfile

    over = []
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                            else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read(fh)
                if int(np.prod(shape, dtype=object)) * dtype.itemsize > info.file_size:
                    over.append(info.filename.removesuffix(".npy"))
    except Exception:  # noqa: BLE001 - a member past reading: the caller's error stands
        return over
    return over


def mapped_members(path: Path, z: "np.lib.npyio.NpzFile", min_bytes: int
                   ) -> dict[str, np.ndarray]:
    """Read-only maps (base-class arrays viewing ``numpy.memmap``) of the members of the
    archive ``z`` at ``path`` that are stored uncompressed, hold no objects and have at least
    ``min_bytes`` bytes of data.

    A stored zip member's bytes are the ``.npy`` file itself: its data start after the local
    file header (30 bytes, the name and the extra field) and the ``.npy`` header.
    """
    import struct
    import zipfile

    out = {}
    with open(path, "rb") as f:
        for info in z.zip.infolist():
            key = info.filename[:-4] if info.filename.endswith(".npy") else None
            if key is None or info.compress_type != zipfile.ZIP_STORED or \
                    info.file_size < min_bytes:
                continue
            f.seek(info.header_offset)
            local = f.read(30)
            if len(local) < 30 or local[:4] != b"PK\x03\x04":
                continue  # let numpy report it
            n_name, n_extra = struct.unpack("<HH", local[26:30])
            f.seek(info.header_offset + 30 + n_name + n_extra)
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0)):
                continue  # numpy's own reader knows the newer headers
            header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                      else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = header(f)
            if dtype.hasobject:
                continue
            mm = np.memmap(path, dtype=dtype, mode="r", offset=f.tell(), shape=shape,
                           order="F" if fortran else "C")
            out[key] = np.asarray(mm)
    return out


def reason(exc: Exception) -> str:
    """A short cause without numpy's advice (its ``allow_pickle`` hint misleads here)."""
    if isinstance(exc, ValueError) and "pickle" in str(exc):
        return "not an .npz archive of arrays"
    return exc.__class__.__name__


def scalar(data: dict, key: str, kind: type, path, what: str,
           error: type[FaceTransferError] = FaceTransferError):
    """``data[key]`` as a Python ``kind`` (int, float, str, bool); else ``error`` naming it."""
    try:
        a = np.asarray(data[key])
        if a.size != 1:
            raise ValueError
        v = kind(a.reshape(()).item()) if kind is not str else str(a.reshape(()))
    except (KeyError, ValueError, TypeError, OverflowError):
        raise error(f"{what} {path}: {key!r} must be one {kind.__name__}") from None
    if kind is float and not np.isfinite(v):
        raise error(f"{what} {path}: {key!r} must be finite, got {v}")
    return v
