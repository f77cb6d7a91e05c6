"""An output's name says what it holds: its extension is checked before any work.

A track written under ``take.mp4`` is a zip archive that a player refuses and a file manager
shows as a video; a glb written under ``face.usd`` is a file USD cannot open; a page written
under ``page.npz`` is found by nothing. Each command that writes one kind of file checks the
name it is given (:func:`check_output_suffix`) before it reads or computes anything, in one
line naming the output, what it holds and the name it could have. (The commands that draw an
image check their own names, ``.png`` or ``.jpg``; a video's is
:func:`facetransfer.io.video.check_video_output`'s.)
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import OutputError

__all__ = ["check_meshes_folder", "check_output_suffix", "suffix_list", "ONE_IMAGE_SUFFIXES",
           "is_one_image", "check_one_image"]

#: The extensions of one image a transfer writes as its one frame (``--out result.png``).
ONE_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def suffix_list(suffixes) -> str:
    """``(".usd", ".usda", ".usdc")`` -> ``".usd, .usda or .usdc"``."""
    s = list(suffixes)
    return s[0] if len(s) == 1 else f"{', '.join(s[:-1])} or {s[-1]}"


def check_output_suffix(path: str | os.PathLike, suffixes, what: str, *, flag: str = "--out",
                        hint: str = "") -> Path:
    """Refuse an output whose extension is not one of ``suffixes``.

    Parameters
    ----------
    path : path-like
        The output.
    suffixes : sequence of str
        Accepted extensions, with the dot, lower case; the first is the one suggested.
    what : str
        What the file holds ("a track").
    flag : str
        The option that named it, for the message.
    hint : str
        Appended to the message (another option that writes what the name asks for).

    Returns
    -------
    Path
        ``path``, whose extension is one of ``suffixes``.

    Raises
    ------
    OutputError
        ``"--out take.mp4: a track is written as .npz, not .mp4; name it take.npz"``.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in suffixes:
        return p
    said = f"not {p.suffix}" if p.suffix else "and the name has no extension"
    name = p.with_suffix(suffixes[0]).name if p.name not in ("", ".", "..") else None
    raise OutputError(f"{flag} {p}: {what} is written as {suffix_list(suffixes)}, {said}"
                      + (f"; name it {name}" if name else "") + hint)



def check_meshes_folder(path: str | os.PathLike, *, overwrite: bool) -> Path:
    """``--meshes``: a folder for ``frame_00000.obj``, ... whose parent exists, not a file, and
    without an earlier run's meshes unless ``overwrite`` (OutputError naming it).

    Returns
    -------
    Path
    """
    md = Path(path)
    if not md.parent.is_dir():
        raise OutputError(f"folder {md.parent} for --meshes does not exist")
    if md.exists() and not md.is_dir():
        raise OutputError(f"--meshes {md} is a file; it names a folder for the meshes "
                          "(frame_00000.obj, ...)")
    if not overwrite and md.is_dir() and any(md.glob("frame_*.obj")):
        raise OutputError(f"{md} already holds meshes; pass --overwrite to replace them")
    from .atomic import probe_folder

    try:            # a folder that cannot be written (read-only, /sys): refused before work
        probe_folder(md / "frame_00000.obj")
    except OutputError as exc:
        raise OutputError(f"--meshes {md}: {exc}") from None
    return md


def is_one_image(path: str | os.PathLike | None) -> bool:
    """Whether ``path`` names one image to write (``result.png``): an image's extension
    (:data:`ONE_IMAGE_SUFFIXES`) and no frame-number field (``%05d``, ``####``: a sequence)."""
    if path is None:
        return False
    p = Path(path)
    return p.suffix.lower() in ONE_IMAGE_SUFFIXES and "%" not in p.name and "#" not in p.name


def check_one_image(path: str | os.PathLike, *, overwrite: bool, inputs=()) -> Path:
    """Validate one image to write (:func:`is_one_image`) before any work: its folder
    exists and can be written, it is none of ``inputs``, and an existing one is replaced
    only with ``overwrite`` (:func:`facetransfer.io.atomic.check_output_path`).

    Raises
    ------
    OutputError
        Not an image's name, or as :func:`~facetransfer.io.atomic.check_output_path`.
    """
    from .atomic import check_output_path

    if not is_one_image(path):
        raise OutputError(f"output {path}: one image is written as "
                          f"{suffix_list(ONE_IMAGE_SUFFIXES)}")
    return check_output_path(path, overwrite=overwrite, inputs=inputs)
