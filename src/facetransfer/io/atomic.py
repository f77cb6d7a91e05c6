"""Atomic output: write to a temporary file beside the target, then rename over it.

An existing output is never overwritten half-way; an interrupted job leaves no partial file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import FaceTransferError


def check_output_path(path: str | os.PathLike, *, overwrite: bool = True) -> Path:
    """Validate an output path: its folder must exist; with ``overwrite=False`` it must not exist.

    Raises
    ------
    FaceTransferError
        If the parent folder does not exist, or the file exists and ``overwrite`` is False.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise FaceTransferError(f"output folder {parent} does not exist (for {p})")
    if not overwrite and p.exists():
        raise FaceTransferError(f"output {p} exists; pass --overwrite to replace it")
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    The temporary file keeps the target's suffix so that writers choosing a format by extension
    (OpenCV, matplotlib, trimesh, numpy) behave as for the final name. On error it is removed.

    Examples
    --------
    >>> with atomic_path("out/model.npz") as tmp:    # doctest: +SKIP
    ...     np.savez(tmp, a=1)
    """
    p = check_output_path(path, overwrite=overwrite)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=f".part{p.suffix}", dir=p.parent or ".")
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes the file private (0600); give the output the usual umask-based mode
        umask = os.umask(0)
        os.umask(umask)
        if tmp_path.exists():
            os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, p)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, *, overwrite: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path."""
    return write_bytes_atomic(path, text.encode("utf-8"), overwrite=overwrite)


def write_image(path: str | os.PathLike, rgb, *, overwrite: bool = True) -> Path:
    """Write an ``(H, W, 3)`` uint8 RGB image atomically (format by extension, OpenCV).

    Raises
    ------
    FaceTransferError
        If OpenCV cannot write that format or file.
    """
    import cv2
    import numpy as np

    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    with atomic_path(path, overwrite=overwrite) as tmp:
        try:
            ok = cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        except cv2.error as exc:  # e.g. an extension OpenCV has no writer for
            raise FaceTransferError(f"cannot write image {path}: "
                                    f"{str(exc).strip().splitlines()[-1]}") from None
        if not ok:
            raise FaceTransferError(f"cannot write image {path}")
    return Path(path)


def save_figure(fig, path: str | os.PathLike, *, overwrite: bool = True, **savefig_kwargs) -> Path:
    """Save a matplotlib figure atomically and close it (``savefig_kwargs``: dpi, bbox_inches…)."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(path, overwrite=overwrite) as tmp:
            fig.savefig(tmp, **savefig_kwargs)
    finally:
        plt.close(fig)
    return Path(path)
