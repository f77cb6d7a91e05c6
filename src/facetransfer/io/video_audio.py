"""A video's sound: which audio streams a media file holds, and how a rewritten video carries
them (:class:`facetransfer.io.video.VideoWriter`): every stream of the input, copied when the
container holds its codec (:data:`COPIED_AUDIO`), else encoded to AAC; cut to the frames
written, muxed by the same ffmpeg process as the frames (:func:`audio_input_args`) or after
the encode (:func:`mux_audio`)."""

from __future__ import annotations

import logging
import os
import re
import subprocess
from pathlib import Path

from .ffmpeg import ffmpeg_error, ffmpeg_exe
from .video_display import checked_timecode, described_input, timecode_args
from .video_options import VIDEO_SUFFIXES
from .video_timeline import first_frame_time

log = logging.getLogger(__name__)

__all__ = ["COPIED_AUDIO", "audio_codec", "audio_codec_args", "audio_codecs", "audio_input_args",
           "audio_seek", "has_audio", "mux_audio"]


def has_audio(path: str | os.PathLike) -> bool:
    """Whether a media file has an audio stream (False when ffmpeg is unavailable)."""
    return audio_codec(path) is not None


def audio_codec(path: str | os.PathLike) -> str | None:
    """The codec of a media file's first audio stream as ffmpeg names it (``"aac"``,
    ``"mp3"``, ``"opus"``, ...); None without one or without ffmpeg."""
    codecs = audio_codecs(path)
    return codecs[0] if codecs else None


def audio_codecs(path: str | os.PathLike) -> tuple[str, ...]:
    """The codecs of every audio stream of a media file, in order (a second language, a
    commentary, a camera's separate channels); empty without one or without ffmpeg."""
    return tuple(re.findall(r"Stream #[^\n]*?: Audio: ([\w-]+)", described_input(path)))


#: Audio codecs copied as they are into the containers that hold them: no second lossy
#: generation, no encoding time (0.2 CPU-s of a 10-second transfer). Other audio becomes AAC.
COPIED_AUDIO = {"aac": ("mp4", "mov", "matroska")}


def audio_codec_args(codecs: tuple[str, ...], fmt: str) -> list[str]:
    """``-c:a`` of audio streams in ``codecs`` written into the container ``fmt`` (ffmpeg's
    name): copied when the container holds every one of them, else all encoded to AAC."""
    copy = bool(codecs) and all(fmt in COPIED_AUDIO.get(c, ()) for c in codecs)
    return ["-c:a", "copy" if copy else "aac"]


def mux_audio(video: str | os.PathLike, audio_from: str | os.PathLike, out: str | os.PathLike, *,
              start: float = 0.0, duration: float | None = None,
              timecode: str | None = None) -> bool:
    """Copy ``video``'s frames and ``audio_from``'s audio into ``out``.

    The video stream is copied as is; the audio too when the container holds its codec
    (:data:`COPIED_AUDIO`), else it is encoded to AAC; it starts at ``start`` seconds after the
    first frame of ``audio_from``'s picture (:func:`audio_seek`: in step with it where the
    sound starts earlier) and is cut to ``duration`` (default: the shorter stream).
    ``timecode``: the start timecode written (:attr:`VideoOptions.timecode`; the video's own
    is not copied). Returns False (and logs why) when there is no ffmpeg or no audio, in which
    case ``out`` is not written.

    Raises
    ------
    VideoError
        If ffmpeg fails (e.g. the disk is full).
    """
    exe = ffmpeg_exe()
    if exe is None:
        log.info("no ffmpeg available (pip install imageio-ffmpeg): output has no audio")
        return False
    codecs = audio_codecs(audio_from)
    if not codecs:
        log.info("%s has no audio track; the output has none either", audio_from)
        return False
    fmt = VIDEO_SUFFIXES.get(Path(out).suffix.lower(), "mp4")
    cmd = [exe, "-hide_banner", "-nostdin", "-loglevel", "error", "-y", "-i", str(video)]
    seek = audio_seek(audio_from, start)
    if seek:
        cmd += ["-ss", f"{seek:.3f}"]
    cmd += ["-i", str(audio_from), "-map", "0:v:0", "-map", "1:a", "-c:v", "copy",
            *audio_codec_args(codecs, fmt)]
    # cut to the video's length; a shorter audio track just ends early
    cmd += ["-shortest"] if duration is None else ["-t", f"{duration:.3f}"]
    if fmt in ("mp4", "mov"):
        cmd += ["-movflags", "+faststart"]
    cmd += [*timecode_args(checked_timecode(timecode), Path(out).suffix.lower()), "-f", fmt,
            str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise ffmpeg_error(res.stderr, f"cannot mux the audio of {audio_from} into {out}")
    return True


def audio_seek(audio_from, start: float = 0.0) -> float:
    """Where in ``audio_from`` (seconds from the file's start, as ffmpeg's input ``-ss``
    counts) the sound of a video written from its frames ``start`` seconds after its first one
    begins: ``start`` plus the time the file's picture starts after its sound
    (:func:`facetransfer.io.video_timeline.first_frame_time`). A phone's clip whose audio leads
    its picture by 0.5 s (an edit list) had its output's sound 0.5 s late before: it was
    taken from the file's start, not from the picture's."""
    return float(start) + first_frame_time(audio_from)


def audio_input_args(audio_from, codecs: tuple[str, ...], fmt: str, *, start: float = 0.0,
                     duration: float) -> list[str]:
    """ffmpeg arguments adding every audio stream of ``audio_from`` (in ``codecs``) as the
    second input of a video written into the container ``fmt``: from ``start`` seconds after
    its picture's first frame (:func:`audio_seek`), cut to ``duration``, copied or encoded as
    :func:`audio_codec_args` says."""
    seek = audio_seek(audio_from, start)
    return [*(["-ss", f"{seek:.3f}"] if seek else []), "-t", f"{duration:.3f}",
            "-i", str(audio_from), "-map", "0:v:0", "-map", "1:a",
            *audio_codec_args(codecs, fmt)]
