"""The ffmpeg binary every video command runs: imageio-ffmpeg's, else one on ``PATH``; and
what its messages say when it fails."""

from __future__ import annotations

import re
import shutil

from ..errors import VideoError

__all__ = ["ffmpeg_error", "ffmpeg_exe", "exit_cause"]


def ffmpeg_exe() -> str | None:
    """Path of an ffmpeg binary (imageio-ffmpeg's, else one on PATH), or None."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - missing package or binary: fall back to PATH
        return shutil.which("ffmpeg")


#: Words of ffmpeg's messages that name why it failed.
_CAUSES = ("No space left", "Disk quota", "File too large", "Permission denied",
           "Read-only file system", "Input/output error")


def ffmpeg_error(stderr: bytes | str, what: str) -> VideoError:
    """A VideoError saying ``what`` failed and why, from ffmpeg's ``stderr``: the line naming
    a cause (a full disk, a permission) if any, else its last line."""
    text = stderr.decode("utf-8", "replace") if isinstance(stderr, bytes) else stderr
    # "[out#0/mp4 @ 0x55d0...] Error closing file: ..." -> "Error closing file: ..."
    lines = [re.sub(r"^\[[^\]]* @ 0x[0-9a-f]+\]\s*", "", ln.strip())
             for ln in text.splitlines() if ln.strip()]
    # the cause (a full disk...) may come before ffmpeg's closing remarks: prefer it
    cause = [ln for ln in lines if any(k in ln for k in _CAUSES)]
    return VideoError(f"{what}: {(cause or lines or ['ffmpeg failed'])[-1]}")


def exit_cause(returncode: int) -> str:
    """How an ffmpeg process ended, for a message: ``"exit status 1"``, ``"killed by signal
    25: file size limit exceeded"`` (SIGXFSZ: a file size limit, ``ulimit -f``)."""
    import signal

    rc = int(returncode)
    why = f"exit status {rc}" if rc >= 0 else f"killed by signal {-rc}"
    if -rc == getattr(signal, "SIGXFSZ", -1):
        why += ": file size limit exceeded"
    return why
