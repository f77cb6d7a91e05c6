"""What the subcommands share: the video options and the model, progress bars, the parsers of
numbers and faces, and the checks of a track or an output named on the command line.

Not a subcommand. ``transfer``, ``puppet``, ``track``, ``demo``, ``synth-video`` and ``batch
transfer`` take the video options ``--codec``/``--crf``/``--preset``...
(:class:`facetransfer.io.video.VideoOptions`); every command given no model uses the default
model (:func:`resolve_model`, :mod:`facetransfer.default_model`), building it once with a
progress bar and a one-line message. ``transfer``, ``puppet`` and ``demo`` share a parser's
making (:func:`subcommand_parser`, :func:`add_output`), the tracker's loading while the model
loads (:func:`load_model_and_mediapipe`) and the library's progress bars (:func:`bar_factory`).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from ..io.video import (CODECS, CRF_RANGE, DEFAULT_CODEC, DEFAULT_CRF, DEFAULT_PRESET, PRESETS,
                        VIDEO_SUFFIXES)

MODEL_HELP = ("multilinear model (.npz); default: the default model (ict-arkit, ARKit "
              "blendshapes), built once into the user cache on first use")
#: The help of the model commands' optional MODEL argument (``model info``, ``render``, ...).
MODEL_ARG_HELP = ("model file (.npz); default: the default model (ict-arkit), built once into "
                  "the user cache on first use")


#: ``--no-progress`` (every command takes it): progress bars off even on a terminal.
_PROGRESS_OFF = False


def set_progress(enabled: bool) -> None:
    """Progress bars on (the default: where stderr is a terminal) or off (``--no-progress``)."""
    global _PROGRESS_OFF
    _PROGRESS_OFF = not enabled


def progress_disabled() -> bool | None:
    """tqdm's ``disable`` for a command's bars: True after ``--no-progress``, else None (tqdm's
    own rule: a bar only where stderr is a terminal, never in a log file or a pipe)."""
    return True if _PROGRESS_OFF else None


def progress_shown() -> bool:
    """Whether a bar would be drawn now: stderr is a terminal and no ``--no-progress``."""
    return not _PROGRESS_OFF and sys.stderr.isatty()


class DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``(default: X)`` after an option's help only where it has a default its help does not
    state already (no "(default: None)", no "default 18 (default: None)", no "(default: [])"
    after a repeatable option given none). "Default" as a word says it; "the flow tracker's
    defaults" (``--speed``'s help) does not, and hid its own default."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False or action.default == [] or \
                re.search(r"\bdefault\b", action.help or "", re.IGNORECASE):
            return action.help
        return super()._get_help_string(action)


def add_command_group(sub, name: str, *, dest: str, metavar: str = "ACTION", **kwargs):
    """Add ``facetransfer NAME ACTION``: a command made of actions, which without one prints
    its help (exit status 2).

    Parameters
    ----------
    sub : argparse subparsers
        Where the command is added.
    name : str
    dest : str
        The namespace attribute that names the action given (``model_command``).
    metavar : str
        The actions' name in the usage line.
    **kwargs
        Passed to ``sub.add_parser`` (``help``, ``description``, ``formatter_class``).

    Returns
    -------
    argparse subparsers
        Where the command's actions are added.
    """
    p = sub.add_parser(name, **kwargs)
    actions = p.add_subparsers(dest=dest, metavar=metavar)
    p.set_defaults(func=lambda args: _usage(p))
    return actions


def _usage(parser: argparse.ArgumentParser) -> int:
    """A command group given no action: its help, exit status 2."""
    parser.print_help()
    return 2


def add_video_options(p: argparse.ArgumentParser, *, what: str = "the video",
                      sequences: bool = True, flag: str = "--out",
                      carries_target: bool = True) -> None:
    """Add ``--codec``, ``--crf`` and ``--preset`` (one definition for every command that
    writes video); ``sequences``: the command also writes image sequences, which the codec
    options do not apply to, and takes ``--start-number`` for them; ``flag``: the option that
    names the video or sequence (``track``'s ``--overlay``); ``carries_target``: the command
    rewrites a target's own frames, so its depth, colour and alpha can be kept (``transfer``;
    not a rendered puppet, an overlay or a synthetic clip, written in 8 bits)."""
    p.add_argument("--codec", choices=tuple(CODECS), default=DEFAULT_CODEC,
                   help=f"codec of {what}: h264 (libx264, yuv420p: plays in browsers), h265 "
                   "(libx265) or prores (ProRes 422 HQ, .mov/.mkv"
                   + ("; 4444 keeping a target's alpha); h265 and prores keep a 10-bit or HDR "
                      "target's depth and colour" if carries_target else ")")
                   + (f"; ignored for an image sequence ({flag} frames/%%05d.png)"
                      if sequences else "") + f"; default {DEFAULT_CODEC}")
    p.add_argument("--crf", type=int, default=None,
                   help=f"constant rate factor of h264/h265, {CRF_RANGE[0]} (best) to "
                   f"{CRF_RANGE[1]}; default {DEFAULT_CRF}")
    p.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, metavar="PRESET",
                   help=f"x264/x265 speed preset, ultrafast ... veryslow (default "
                   f"{DEFAULT_PRESET}): slower ones cost more CPU for slightly better quality "
                   "at the same CRF (medium: 1.6x the CPU, +0.07 dB); h264 at faster, given "
                   "or not, is x264's faster without B-frames' 8x8 partitions (11-18 %% less "
                   "of the encoder's CPU, the same quality), any other preset x264's own")
    if sequences:
        p.add_argument("--start-number", type=_start_number, default=None, metavar="N",
                       help=f"number of an image sequence's first frame ({flag} "
                       "shot/%%04d.exr --start-number 1001); default: a plate "
                       + ("target" if carries_target else "input") + "'s own first number, "
                       "else 0")


def option_with(value, default, flag: str, given_with, with_flag: str):
    """``flag``'s ``value``, or ``default`` where it was not given (None); refused, naming
    both, where it is given without ``with_flag`` (``given_with`` false), the only option it
    acts with (``texture lift --k`` without ``--function``: it was ignored in silence)."""
    if value is not None and not given_with:
        from ..errors import FaceTransferError

        raise FaceTransferError(f"{flag} acts only with {with_flag}, which is not given: give "
                                f"{with_flag} or leave {flag} out")
    return default if value is None else value


#: What ``--face`` / ``--target-face`` / ``--source-face`` take
#: (:func:`facetransfer.track.face_crop.subject_point`).
FACE_WHERE = ("left, right, centre, or pixels X,Y near the face (default: the face found "
              "first)")


def check_face(text: str | None, video, flag: str = "--face", tracker: str = "auto") -> None:
    """``flag``'s value placed in ``video``'s frame (:func:`facetransfer.track.face_crop.
    subject_point`), so that a face option it cannot place, or one given to a ``tracker`` other
    than the capture tracker (which alone follows a face said), fails before any work, naming
    ``flag``; nothing for None."""
    if text is None:
        return
    if tracker not in ("auto", "capture"):
        from ..errors import FaceTransferError

        raise FaceTransferError(f"{flag} is for the capture tracker (--tracker auto or "
                                f"capture), not --tracker {tracker}, which follows the face "
                                "found first")
    from ..io.video import video_info
    from ..track.face_crop import subject_point

    subject_point(text, video_info(video).size, what=flag)


def video_out(text: str) -> str:
    """A video output's argument, an image sequence's ``####`` field written as printf's
    (``out/sh010.####.png`` -> ``out/sh010.%04d.png``), as input sequences are named."""
    from ..io.video_sequence import is_sequence, percent_pattern

    return str(percent_pattern(text)) if "#" in text and is_sequence(text) else text


#: The largest ``--start-number``: a frame number of 32 bits (a DPX header's, ffmpeg's
#: image-sequence reader's); 10**30 was taken, its frames named with 31 digits.
MAX_START_NUMBER = 2 ** 31 - 1


def _start_number(text: str) -> int:
    """``--start-number``'s value: an integer from 0 to :data:`MAX_START_NUMBER` (argparse
    names the option)."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    if n > MAX_START_NUMBER:
        raise argparse.ArgumentTypeError(f"expected a frame number of at most "
                                         f"{MAX_START_NUMBER} (32 bits), got {text!r}")
    return n


def video_options(args, out=None):
    """The :class:`~facetransfer.io.video.VideoOptions` of parsed arguments (validated);
    ``out``: the command's video output, which ``--start-number`` must name an image
    sequence (else a :class:`~facetransfer.errors.FaceTransferError`)."""
    from ..io.video import VideoOptions, is_image_pattern

    first = getattr(args, "start_number", None)
    if first is not None and (out is None or not is_image_pattern(out)):
        from ..errors import FaceTransferError

        raise FaceTransferError(f"--start-number numbers image sequences only (e.g. "
                                f"shot/%04d.exr), not the video {out}" if out is not None else
                                "--start-number numbers image sequences only, and none is "
                                "written here")
    return VideoOptions(codec=args.codec, crf=args.crf, preset=args.preset, first_number=first)


def tqdm_progress(desc: str, *, unit: str = "item", enabled: bool = True):
    """A ``(done, total)`` progress callback drawing a tqdm bar on stderr (a terminal only),
    and the function that closes it: ``(callback, close)``."""
    state: dict = {}

    def callback(done: int, total: int) -> None:
        if "bar" not in state:
            from tqdm import tqdm

            state["bar"] = tqdm(total=total, desc=desc, unit=unit, leave=False,
                                dynamic_ncols=True, file=sys.stderr,
                                disable=True if not enabled else progress_disabled())
        bar = state["bar"]
        bar.total = total
        bar.update(done - bar.n)

    def close() -> None:
        if "bar" in state:
            state["bar"].close()

    return callback, close


def number_in(lo: float, hi: float | None, *, integer: bool = False):
    """An argparse ``type`` taking a number in ``[lo, hi]`` (an integer with ``integer``; no
    upper bound where ``hi`` is None); argparse names the option in its one line ("argument
    --smooth: expected ...")."""
    kind = "an integer" if integer else "a number"

    def parse(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            v = None
        if v is None or not lo <= v <= (float("inf") if hi is None else hi):
            shown = [f"{int(b)}" if integer else f"{b:g}" for b in (lo, hi or 0)]
            within = f">= {shown[0]}" if hi is None else f"in [{shown[0]}, {shown[1]}]"
            raise argparse.ArgumentTypeError(f"expected {kind} {within}, got {text!r}")
        return v

    return parse


def integer_from(lo: int):
    """An argparse ``type`` taking an integer >= ``lo`` (:func:`number_in` without an upper
    bound: a seed, a count of frames; before, a seed of -1 was numpy's "expected non-negative
    integer", naming nothing, or taken)."""
    return number_in(lo, None, integer=True)


def frame_count(n: int) -> str:
    """``"1 frame"``, ``"N frames"``: the count of a command's summary line."""
    return f"{n} frame" if n == 1 else f"{n} frames"


def announce(message: str) -> None:
    """A library's one-line message (e.g. that the default model is being built) on stderr."""
    print(message, file=sys.stderr, flush=True)


def resolve_model(path, *, progress: bool = True):
    """``load_model(path)``, or the default model when ``path`` is None (built on first use
    with a tqdm bar on stderr, announced in one line).

    Returns
    -------
    MultilinearModel
    """
    if path is not None:
        from ..model import load_model

        return load_model(path)
    from ..default_model import load_default_model

    on_progress, close = tqdm_progress("default model", unit="identity", enabled=progress)
    try:
        return load_default_model(progress=on_progress, announce=announce)
    finally:
        close()


def check_track_of(track, path, video, n_frames: int, size, purpose: str) -> None:
    """``track`` (read from ``path``) checked against ``video``'s ``n_frames`` frames of
    ``size`` (:meth:`facetransfer.track.result.Track.check_video`); a track of its first frames
    (its size, fewer frames: ``track --max-frames``) is said with the ``--max-frames`` that
    ``purpose`` (e.g. "to draw the frames it covers") needs."""
    from ..errors import FaceTransferError

    if track.n_frames < n_frames and tuple(track.frame_size) == tuple(int(v) for v in size):
        raise FaceTransferError(f"track {path} has {track.n_frames} frames, the video {video} "
                                f"{n_frames}: give --max-frames {track.n_frames} {purpose}")
    track.check_video(n_frames, size, what=f"video {video}")


def check_output_name(path, suffixes, what: str, *, flag: str = "--out", hint: str = "") -> Path:
    """:func:`facetransfer.io.output_names.check_output_suffix`, an existing folder first
    refused as one: ``edit T.npz --out out/`` was told "the name has no extension; name it
    out.npz", a file beside the folder meant.

    Raises
    ------
    OutputError
        ``"--out tracks is a folder; give a file name in it (tracks/NAME.npz)"``, or as
        :func:`~facetransfer.io.output_names.check_output_suffix`.
    """
    from ..errors import OutputError
    from ..io.output_names import check_output_suffix

    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{flag} {p} is a folder; give a file name in it "
                          f"({p / ('NAME' + suffixes[0])})")
    return check_output_suffix(path, suffixes, what, flag=flag, hint=hint)


def check_track_name(path, flag: str = "--out", *, overlay: bool = False) -> None:
    """A track file's name ends in .npz (:func:`check_output_name`); with ``overlay``
    (``track``), a video's name is pointed to ``--overlay``."""
    video = overlay and Path(path).suffix.lower() in VIDEO_SUFFIXES
    check_output_name(path, (".npz",), "a track", flag=flag,
                        hint=" (--overlay writes a video of the fitted mesh over the clip)"
                        if video else "")


def default_model_for(track):
    """The default model for a track given without ``--model`` (built once with a progress bar;
    an error asking for ``--model`` if the track was made with another model)."""
    from ..export.common import resolve_model as of_track

    progress, close = tqdm_progress("default model", unit="identity")
    try:
        return of_track(track, progress=progress, announce=announce)
    finally:
        close()


# --------------------------------------------------------------------------------------------
# what the commands that track and render share (transfer, puppet, demo)
# --------------------------------------------------------------------------------------------

def bar_factory():
    """``factory(desc, total) -> tqdm`` for library progress (stderr), or None after
    ``--no-progress``."""
    if progress_disabled():
        return None
    from tqdm import tqdm

    def make(desc, total):
        return tqdm(total=total, desc=desc, unit="frame", leave=False, dynamic_ncols=True,
                    file=sys.stderr, disable=progress_disabled())

    return make


def subcommand_parser(sub, name: str, help: str, description: str):
    """A subcommand's parser with the defaults shown in its help."""
    return sub.add_parser(name, formatter_class=DefaultsFormatter, help=help,
                          description=description)


def add_output(p, func, *, metavar: str, help: str | None = None, video: bool = False,
               overwrite_help: str = "replace an existing output",
               carries_target: bool = True) -> None:
    """``--out`` (with the video options when ``video``, ``carries_target`` as
    :func:`add_video_options`), ``--overwrite`` and the function that runs the
    subcommand."""
    p.add_argument("--out", required=True, metavar=metavar, help=help,
                   type=video_out if video else str)
    if video:
        add_video_options(p, carries_target=carries_target)
    p.add_argument("--overwrite", action="store_true", help=overwrite_help)
    p.set_defaults(func=func)


def tracker_name(value: str) -> str:
    """``--tracker``: ``klt`` (what ``track`` calls the paper's optical-flow tracker) is
    ``flow`` here."""
    return {"klt": "flow"}.get(value, value)


def check_positive(value, name):
    """A count option (``--max-frames``, ``--frames``) None or at least 1, else one line."""
    from ..errors import FaceTransferError

    if value is not None and int(value) < 1:
        raise FaceTransferError(f"{name} must be >= 1, got {value}")


def check_landmarks_file(video, tracker: str) -> None:
    """A damaged ``NAME.mediapipe478.npz`` beside a video: one line naming it, before any work
    (only for ``--tracker landmarks``, the one tracker that reads it)."""
    if tracker != "landmarks":
        return
    from ..io.landmarks import read_mediapipe_landmarks
    from ..track.obtain import landmarks_file

    lmf = landmarks_file(video)
    if lmf is not None:
        read_mediapipe_landmarks(lmf)


def start_tracker_loads(will_track: bool):
    """When videos will be tracked, MediaPipe imported and the capture's compiled kernels
    loaded on threads from now on (:func:`facetransfer.track.detect.preload_mediapipe`,
    :func:`facetransfer.track.capture.load_kernels`); returns ``wait()``, to be called before
    the tracking forks its background process, which then inherits them."""
    if not will_track:
        return lambda: None
    import threading

    from ..track.capture import load_kernels
    from ..track.detect import preload_mediapipe

    wait = preload_mediapipe()
    kernels = threading.Thread(target=load_kernels, name="load-kernels", daemon=True)
    kernels.start()

    def done():
        wait()
        kernels.join()

    return done


def load_model_and_mediapipe(path, will_track: bool, *, progress: bool = True):
    """The model (``--model`` ``path`` or the default), with :func:`start_tracker_loads`'
    threads running meanwhile and done when this returns."""
    wait = start_tracker_loads(will_track)
    try:
        return resolve_model(path, progress=progress)
    finally:
        wait()
