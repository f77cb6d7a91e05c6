"""The ffmpeg binary every video command runs: imageio-ffmpeg's, else one on ``PATH``."""

from __future__ import annotations

import shutil

__all__ = ["ffmpeg_exe"]


def ffmpeg_exe() -> str | None:
    """Path of an ffmpeg binary (imageio-ffmpeg's, else one on PATH), or None."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - missing package or binary: fall back to PATH
        return shutil.which("ffmpeg")
