"""A Live Link Face take as the expression source of a transfer (§6, Fig. 7C with a recorded
performance).

An animator records a take with Epic Games' Live Link Face app (an iPhone's ARKit tracker: 52
blendshape activations and the head's rotation per row, :mod:`facetransfer.export.livelink`)
and wants the person in some footage to perform it: ``facetransfer transfer --target T.mp4
--expression-from take.csv``. For a model whose expressions are ARKit blendshapes (the default
``ict-arkit``) the activations are expression weights exactly (Eq. (A),
:func:`facetransfer.arkit.activations_to_weights`), so the take is a new performance without
any tracking of the source: the target's own track with its expression weights replaced by the
take's, resampled to the target's frames by the take's timecodes. Identity and head pose stay
the target's (as for a video source); the eyes look where the take's eyeLook* say. A take has
no pictures, so the mouth's texture comes from the target's own frames (the texture function
of §6 queried with the new expression, as for a ready performance).

Timecodes are ``HH:MM:SS:FF.mmm``: ``FF`` a frame at the take's nominal rate, ``.mmm`` its
thousandths. The rate is not written in the file: a take that passes a second shows it (its
frame numbers wrap after the last, :func:`take_rate`); one within a second is read at 30 or
60 a second where its labels have thousandths (the app's, as Unreal's importer reads them),
else at the smallest usual rate above its frame numbers, with a warning. A take recorded
beside the camera with synced clocks is placed by the target's start timecode
(:data:`TAKE_SYNCS`).

:func:`take_track` makes a take a track of its own (the model's person performing it with the
take's head rotation): what ``facetransfer puppet take.csv`` renders and ``facetransfer view
take.csv`` shows; a photo as the target of ``transfer`` performs the take over the same
frames (:func:`take_length`: the take's rows at their rate, the photo's head held).
:func:`edit_take` edits a take's curves as a track's are edited and writes a
take again, the rest of the file as it was (``facetransfer edit take.csv``).

:func:`~facetransfer.io.video_display.timecode_seconds` is :mod:`facetransfer.io.video_display`'s,
importable from here too.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from io import StringIO
from pathlib import Path

import numpy as np

from .io.video_display import timecode_seconds
from .transfer import TransferError

log = logging.getLogger(__name__)

__all__ = ["TIMECODE_RATES", "TAKE_SYNCS", "PREVIEW_SIZE", "Take", "is_take", "timecode_seconds",
           "take_rate", "take_seconds", "take_row_rate", "take_on_timeline", "take_performance",
           "take_length", "take_track", "EditedTake", "edit_take"]

#: The frame size of a take shown on a model (:func:`take_track`, ``facetransfer puppet``).
PREVIEW_SIZE = (512, 512)

#: Nominal timecode rates (frames per second) a take's ``FF`` field may count in.
TIMECODE_RATES = (24, 25, 30, 48, 50, 60, 100, 120)


#: How a take is placed on the target's timeline: ``"timecode"``, the target's start timecode
#: found among the take's (where both have one; else as ``"start"``); ``"start"``, the take's
#: first row at the target's first frame.
TAKE_SYNCS = ("timecode", "start")

#: The longest a take's consecutive rows may lie apart (seconds): the app writes a row every
#: frame; a longer gap is two recordings in one file or a damaged timecode (rows 23 hours
#: apart made ``view`` and ``puppet`` fill two million frames, holding the first row).
MAX_ROW_GAP = 60.0


@dataclass(frozen=True)
class Take:
    """A take standing for the new performance of a transfer until the target is tracked
    (:func:`facetransfer.transfer_plan.plan_sources`): its file, time alignment, and the
    target's start timecode at its frame rate (None: placed at the take's first row)."""

    path: Path
    align: str | None = None
    start_timecode: str | None = None

    def performance(self, target_track, model):
        """:func:`take_performance` on ``target_track``'s timeline."""
        return take_performance(self.path, target_track, model, align=self.align,
                                start_timecode=self.start_timecode)


def is_take(path) -> bool:
    """Whether an expression source names a Live Link Face take (a ``.csv`` file) rather than
    a video."""
    return path is not None and Path(os.fspath(path)).suffix.lower() == ".csv"


def _timecode_fields(timecodes, name: str = "the take") -> np.ndarray:
    """:func:`facetransfer.export.livelink.timecode_fields` (hours, minutes, seconds, frame,
    thousandths), a timecode that is not one, or of hours or minutes past a day's, a
    TransferError (before, ``99:02:03:00`` was read as 4 days on; ``name``: the take, as said).
    Seconds past 59 are read on into the next minute (written so by a clock that counts
    them)."""
    from .export.common import ExportError
    from .export.livelink import timecode_fields

    try:
        f = timecode_fields(timecodes)
    except ExportError as exc:
        raise TransferError(str(exc)) from None
    odd = (f[:, 0] > 23) | (f[:, 1] > 59)
    if odd.any():
        k = int(np.flatnonzero(odd)[0])
        raise TransferError(f"{name}'s timecode {timecodes[k]} at row {k + 1} is not a time of "
                            "day (hours 00-23, minutes 00-59)")
    return f


def take_rate(timecodes, *, warn: bool = True) -> int:
    """The nominal rate of a take's timecodes: the smallest of :data:`TIMECODE_RATES` above
    every frame number ``FF`` it holds. Sure where the take passes a second (its frame numbers
    wrap after the last one of its rate); a take within one second whose labels have
    thousandths of a frame (the app's) is read at 30 or 60 as Unreal's importer reads it, any
    other is said in the log to be a guess. TransferError beyond every rate."""
    return _rate(_timecode_fields(timecodes), warn)


def _rate(f: np.ndarray, warn: bool, name: str = "the take") -> int:
    """:func:`take_rate` of parsed timecode fields ``f`` (F, 5); ``name``: the take, as its
    guess is said (a batch worker's line names it)."""
    top = int(f[:, 3].max(initial=0))
    seconds = f[:, 0] * 3600 + f[:, 1] * 60 + f[:, 2]
    wrapped = bool(seconds.size) and seconds.max() > seconds.min()
    if not wrapped and f[:, 4].any() and top < 60:
        # thousandths of a frame: the app's labels (and an export's, --take-rate app), counted
        # at 30 or 60 a second; read as Unreal's importer reads them (60 where a frame number
        # passes 29, else 30), not guessed
        return 60 if top >= 30 else 30
    for rate in TIMECODE_RATES:
        if rate > top:
            if warn and not wrapped:
                log.warning("%s lies within one second of timecode: its frames are taken at "
                            "%d a second (the smallest timecode rate above its frame numbers)",
                            name, rate)
            return rate
    raise TransferError(f"timecode frame {top} of {name} is beyond every timecode rate "
                        f"({TIMECODE_RATES[-1]} fps)")


def take_seconds(timecodes, *, warn: bool = True, name: str = "the take") -> np.ndarray:
    """``(F,)`` seconds of each row after the take's first on its timecodes' clock (frames of
    the nominal :func:`take_rate` a second: a 23.976 fps plate's export spans 0.1 % less than
    its frames; ``warn``: the rate's guess said; TransferError if they go back in time, a day
    added past midnight)."""
    t = _clock(timecodes, warn, name)
    return t - (t[0] if t.size else 0.0)


def _clock(timecodes, warn: bool, name: str = "the take") -> np.ndarray:
    """``(F,)`` seconds since midnight of each row's timecode, counted at :func:`take_rate`;
    TransferError where they go back in time."""
    f = _timecode_fields(timecodes, name)
    t = _seconds(f, _rate(f, False, name), timecodes, name)
    _rate(f, warn, name)    # its guess said once the take is known to be readable
    return t


def _seconds(f: np.ndarray, rate: int, timecodes, name: str = "the take") -> np.ndarray:
    """``(F,)`` seconds since midnight of parsed timecode fields ``f`` (F, 5) counted at
    ``rate`` (a day added past midnight); TransferError where they go back in time or
    repeat (``name``: the take, as said)."""
    t = (f[:, 0] * 3600 + f[:, 1] * 60 + f[:, 2]) + (f[:, 3] + f[:, 4] / 1000.0) / rate
    t = _past_midnight(t, 86400.0)
    _forward(t, timecodes, name)
    return t


def take_on_timeline(seconds: np.ndarray, values: np.ndarray, n_frames: int, fps: float, *,
                     align: str | None = None, start: float = 0.0) -> np.ndarray:
    """A take's rows ``values`` (F, k) at ``seconds`` (F,) resampled to frames
    ``start + j / fps``, linearly between rows.

    ``start``: the take's time (seconds after its first row) at frame 0. ``align`` as
    :func:`facetransfer.transfer.time_map`: ``"trim"`` stops at the end of its last row's own
    span, ``"hold"`` holds its last row, ``"loop"`` restarts it after that span. A row's span
    is the rows' median step (:func:`_row_step`): a take of 90 rows at 30 a second lasts 3 s,
    as a 90-frame video of 30 fps does, on a target of any rate (trimmed on a 60 fps target
    it keeps 180 frames; looped, each repeat starts on its first row). A frame within
    ``_SLACK`` of a target frame short of the span is past it: trimmed, or a repeat's first
    row (the span from time-of-day timecodes lands an ulp off a target frame).
    None: ``"trim"`` when the take is at least as long as the ``n_frames``, else ``"hold"``.

    Returns
    -------
    (m, k) float64
        ``m = n_frames`` except with ``"trim"`` (the frames the take covers, at least 1).
    """
    t, v = np.asarray(seconds, np.float64), np.asarray(values, np.float64)
    if align not in (None, "trim", "hold", "loop"):
        raise TransferError(f"align must be trim, hold or loop, got {align!r}")
    end = float(t[-1]) if t.size else 0.0
    when = float(start) + np.arange(int(n_frames)) / float(fps)
    span = end + _row_step(t, fps)               # the take's end: its last row's span too
    if align is None:
        align = "trim" if end >= when[-1] else "hold"
    if align == "trim":
        when = when[when < span - _SLACK / fps] if end > when[0] else when[:1]
    elif align == "loop" and end > 0:
        when = np.mod(when, span)
        when[when > span - _SLACK / fps] = 0.0   # a repeat's start, not an ulp short of it
    return np.stack([np.interp(when, t, v[:, c]) for c in range(v.shape[1])], axis=1) \
        if v.shape[1] else np.zeros((when.size, 0))


def take_performance(path, target_track, model, *, align: str | None = None,
                     start_timecode: str | None = None):
    """The performance of the target's person acting a Live Link Face take (module notes).

    Parameters
    ----------
    path : path-like
        The take (CSV, :func:`facetransfer.export.livelink.read_livelink`).
    target_track : Track
        The target's own track: its identity, pose, timeline and lost frames.
    model : MultilinearModel
        With ARKit-named expressions (:func:`facetransfer.arkit.is_arkit_model`).
    align : {"trim", "hold", "loop"}, optional
        See :func:`take_on_timeline`.
    start_timecode : str, optional
        The target's start timecode (:func:`facetransfer.io.video_display.timecode_of`): where
        the take's timecodes span it, the take is placed by it (a take recorded beside the
        camera, both clocks synced); else from the take's first row (said in the log).

    Returns
    -------
    Track
        On the target's timeline (its frames, or those the take covers with ``"trim"``), with
        ``landmarks2d`` and ``blendshapes`` recomputed.

    Raises
    ------
    TransferError
        The model's expressions are not ARKit's, or the take is not one.
    """
    from .arkit import activations_to_weights, attach_activations
    from .io.frame_numbers import track_first_number
    from .track.project import project_landmarks, take_frames

    take = _read(path, model)
    clock, first = _take_clock(take.timecodes, target_track.fps, start_timecode,
                               f"take {path}")
    t = clock - clock[0]
    start = _synced_start(take.timecodes, clock, start_timecode, first, path)
    a = take_on_timeline(t, take.activations, target_track.n_frames, target_track.fps,
                         align=align, start=start)
    _say_held(path, float(t[-1]) - start + _row_step(t, target_track.fps), len(a),
              target_track.fps, align, track_first_number(target_track),
              take_row_rate(t, take.timecodes) if len(t) > 1 else None)
    new = take_frames(target_track, np.arange(len(a)))
    weights = dict(new.weights)
    weights["expression"] = activations_to_weights(model, np.clip(a, 0.0, 1.0))
    new = dataclasses.replace(new, weights=weights)
    return attach_activations(project_landmarks(new, model), model)


#: A target frame this much (of a frame) short of a take's end is past it: the app's
#: thousandths of a frame place a row up to 1/60000 s off its clip's frame (a 23.976 fps
#: take's end needs 2e-4). Less than 1/1001: an NTSC rate beside a whole one puts a target
#: frame that much inside a take's end, which the video keeps (1e-3 dropped it).
_SLACK = 5e-4


def _row_step(t: np.ndarray, fps: float) -> float:
    """How long one of a take's rows at ``t`` (seconds) lasts: their median step, or one
    frame of ``fps`` for a take of one row."""
    return float(np.median(np.diff(t))) if np.size(t) > 1 else 1.0 / float(fps)


def _say_held(path, left: float, n: int, fps: float, align: str | None,
              first: int = 0, rows: float | None = None) -> None:
    """Warn where a take that ends ``left`` seconds after the target's first frame (its last
    row's span included) leaves the last of its ``n`` frames (at ``fps``) holding its last
    row (``align`` None or "hold"): the performance stands still there, which the user would
    not see coming. The target's frames numbered from ``first`` (a plate's first number); the
    take's ``rows`` a second said where they are not the target's frames a second (a plate
    that stores no rate, read at 24 fps, under a take of 30: it ends a fifth early)."""
    if align not in (None, "hold") or n < 1:
        return
    k = max(int(np.ceil(left * fps - _SLACK)), 1)     # the frames the take's rows reach
    if k < n:
        rates = "" if rows is None or abs(rows - fps) <= 1e-3 * fps else \
            f" (its rows {rows:g} a second, the target's frames {fps:g})"
        log.warning("the take %s ends at the target's frame %d%s: its last row is held on "
                    "frames %d-%d (--align trim stops the result there, loop repeats the "
                    "take)", path, first + max(k - 1, 0), rates, first + max(k, 0),
                    first + n - 1)


def _take_clock(timecodes, fps: float, start_timecode: str | None, name: str
                ) -> tuple[np.ndarray, float | None]:
    """``(F,)`` seconds of each row of a take on the target's clock, and the target's first
    frame's (None without ``start_timecode``). A take of whole frames at the target's own
    timecode rate (``round(fps)``: one exported from it) counts its frames: a row's time is
    the frames its timecode counts over ``fps`` (a 23.976 fps plate's frame 1000 after
    01:00:00:00 is 01:00:41:16, at 41.708 s); a take at another rate, with sub-frames (the
    app's), or beside a drop-frame start, counts clock time (:func:`_seconds`)."""
    from .io.plate_header import timecode_count

    f = _timecode_fields(timecodes, name)
    nominal, whole = round(float(fps)), not f[:, 4].any()
    secs = f[:, 0] * 3600 + f[:, 1] * 60 + f[:, 2]
    short = not (secs.size and secs.max() > secs.min())       # within one second: no rate shown
    # a short take of whole frames is taken at the target's rate (else the guess is said)
    rate = nominal if whole and short and f[:, 3].max(initial=0) < nominal \
        else _rate(f, True, name)
    count, drop = (0, False) if start_timecode is None else timecode_count(start_timecode, fps)
    # rows of whole frames (an export's; the app's carry thousandths, its clock's time), not
    # after a drop-frame start (then an export counts clock time, export.livelink)
    if rate != nominal or drop or not whole:
        clock = _seconds(f, rate, timecodes, name)
        first = None if start_timecode is None else timecode_seconds(start_timecode, fps)
        return clock, _same_day(first, clock, 86400.0)
    frames = _past_midnight(secs * rate + f[:, 3], 86400 * rate)
    _forward(frames, timecodes, name, rate)
    first = None if start_timecode is None else count / float(fps)
    clock = frames / float(fps)
    return clock, _same_day(first, clock, 86400.0 * rate / fps)


def _past_midnight(t: np.ndarray, day: float) -> np.ndarray:
    """Row times ``t`` with a ``day`` added after each step back of more than half of one: a
    take past midnight, whose timecodes start again at ``00:00:00:00``."""
    if t.size < 2:
        return t
    back = np.diff(t) < -day / 2
    return t + day * np.concatenate([[0], np.cumsum(back)])


def _same_day(first: float | None, clock: np.ndarray, day: float) -> float | None:
    """The target's first frame ``first`` a ``day`` later where the take's rows (``clock``)
    pass midnight before it."""
    if first is not None and clock.size and first < clock[0] <= first + day <= clock[-1]:
        return first + day
    return first


def _forward(t: np.ndarray, timecodes, name: str = "the take", per_second: float = 1.0
             ) -> None:
    """TransferError where a take's row times ``t`` (``per_second`` units a second) go back
    in time, stand still (two rows of one timecode: which to show is unknown; before, ten rows
    of one timecode made a take of one frame, said nowhere) or leap more than
    :data:`MAX_ROW_GAP`; ``name``: the take, as said."""
    step = np.diff(t) / per_second
    odd = (step <= 0) | (step > MAX_ROW_GAP)
    if not odd.any():
        return
    k = int(np.flatnonzero(odd)[0]) + 1
    how = "go back in time" if step[k - 1] < 0 else "repeat" if step[k - 1] == 0 else \
        f"leap {step[k - 1]:.0f} s"
    tail = f": rows at most {MAX_ROW_GAP:.0f} s apart are read" if step[k - 1] > 0 else ""
    raise TransferError(f"{name}'s timecodes {how} at row {k + 1} "
                        f"({timecodes[k]} after {timecodes[k - 1]}){tail}")


def _synced_start(timecodes, clock: np.ndarray, start_timecode: str | None,
                  first: float | None, path) -> float:
    """Seconds into the take (rows at ``clock``) at the target's first frame (``first`` on the
    same clock, its timecode ``start_timecode``): where the take's rows span it, that moment
    (said in the log); else 0."""
    if start_timecode is None or first is None:
        return 0.0
    offset = first - float(clock[0])
    if 0.0 <= offset <= float(clock[-1] - clock[0]):
        # at its first row: the take and the target start together, nothing to say
        say = log.info if offset < 1e-6 else log.warning
        say("the take %s is placed by timecode: the target's first frame (%s) is %.3f s into "
            "it (--take-sync start would place it from its first row)", path, start_timecode,
            offset)
        return offset
    log.warning("the take %s (timecodes %s to %s) does not span the target's start timecode "
                "%s: placed from its first row", path, timecodes[0], timecodes[-1],
                start_timecode)
    return 0.0


def _read(path, model):
    """The take at ``path`` (lenient, :func:`facetransfer.export.livelink.read_livelink`) for a
    model of ARKit expressions; TransferError otherwise, or without rows. Columns of shapes it
    lacks are said once."""
    from .arkit import is_arkit_model
    from .export.livelink import POSE_COLUMNS

    if not is_arkit_model(model):
        raise TransferError(f"a Live Link Face take ({path}) drives a model whose expressions "
                            "are ARKit blendshapes (the default model, 'ict-arkit')")
    take = _load(path)
    shapes = [n for n in take.missing if n not in POSE_COLUMNS]
    head = [n for n in POSE_COLUMNS if n.startswith("Head")]
    if any(n not in take.missing for n in head):   # a head's rotation, in part: said too
        shapes += [n for n in head if n in take.missing]
    if shapes:
        log.warning("the take %s has no column %s: taken as 0", path, ", ".join(shapes))
    return take


def _load(path):
    """The take at ``path`` read leniently (:func:`facetransfer.export.livelink.read_livelink`);
    TransferError where it is none, or has no rows."""
    from .export.common import ExportError
    from .export.livelink import read_livelink

    try:
        take = read_livelink(path, lenient=True)
    except (ExportError, OSError, UnicodeDecodeError) as exc:
        said = str(exc)    # the reader's messages name the file already: not twice
        raise TransferError(said if str(path) in said else f"{path}: {said}") from None
    if not len(take.timecodes):
        raise TransferError(f"the take {path} has no rows")
    return take


@dataclass(frozen=True)
class EditedTake:
    """A take written by :func:`edit_take`: its path, its rows, and the columns that changed
    (the take's own names for them, in its order)."""

    path: Path
    n_rows: int
    changed: tuple[str, ...]


def edit_take(path, out, *, add=(), scale=(), ramp: int = 8,
              overwrite: bool = False) -> EditedTake:
    """Write the Live Link Face take at ``path`` to ``out`` with its ARKit curves edited (what
    ``facetransfer edit take.csv`` does; beyond the paper, its Fig. 7E edit on a recorded take).

    The curves are edited as a track of an ARKit model is
    (:func:`facetransfer.performance_edit.edit_activations`: ``scale`` multiplies a curve,
    ``add`` adds an activation over rows ``START..END`` with
    :func:`facetransfer.performance_edit.ramp_envelope`'s ramps, each value the edit changes
    clipped to [0, 1]: a value the app wrote past 1 the edit does not move is kept); frames are the take's on its
    timeline, 0-based, as ``view`` and ``puppet`` of it number them (its rows, where none is
    dropped: :func:`_row_frames`). Everything else is kept byte for byte: the header and its column order, the
    timecodes, ``BlendShapeCount``, the head and eye rotation columns, the line endings, a
    byte-order mark; so is every field of an edited curve whose value the edit leaves as it was.
    An edited field is written with 8 decimals (as ``export`` writes a take). The eye rotation
    columns are not worked out again from edited ``eyeLook*`` curves (said in the log).

    Parameters
    ----------
    path, out : path-like
        The take, and the edited take to write (atomically; ``overwrite``: replace one there).
    add, scale : EditAdd / EditScale, their text, or sequences of them
        As :func:`facetransfer.performance_edit.edit_track` takes them
        (``"jawOpen*0.5@10-40"``, ``"jawOpen=2"``); a name is one of the 52 ARKit names or a word for both sides.
    ramp : int
        Rows over which an addition eases in before its range and out after it.

    Returns
    -------
    EditedTake

    Raises
    ------
    TransferError
        The take is none (or has no rows, or timecodes that repeat or go back), an unknown
        name (the closest one named), a curve the take has no column for, a range outside its
        frames, a negative factor.
    """
    from .arkit import ARKIT_NAMES
    from .io.atomic import write_text_atomic
    from .performance_edit import edit_activations

    if int(ramp) < 0:
        raise TransferError(f"ramp must be >= 0 frames, got {ramp}")
    take = _load(path)
    has = np.array([_column_name(n) not in take.missing for n in ARKIT_NAMES])
    after = edit_activations(take.activations, scale=scale, add=add, ramp=int(ramp), has=has,
                             owner=f"the take {path}", frames=_row_frames(take, path))
    text = Path(path).read_bytes().decode("utf-8")
    new, changed = _edited_text(text, take.activations, after)
    if any(n.startswith("eyeLook") for n in changed):
        log.warning("the eye rotation columns (LeftEyeYaw, ...) of %s are kept as recorded; "
                    "they no longer follow its edited eyeLook curves", out)
    written = write_text_atomic(out, new, overwrite=overwrite)
    return EditedTake(written, len(take.timecodes), tuple(_column_name(n) for n in changed))


def _row_frames(take, path) -> np.ndarray:
    """``(F,)`` the frame of each of a take's rows on its timeline, as :func:`take_track`
    lays them out (what ``view``, ``puppet`` and ``--neutral FRAME`` count): the nearest one
    (an app's rows jitter by a few thousandths), its last frame at most; row ``k`` where no row
    is dropped (before, always row ``k``: a take whose rows skip frames was edited later than
    asked). TransferError where its timecodes repeat or go back."""
    t = take_seconds(take.timecodes, warn=False, name=f"take {path}")
    at = t * take_row_rate(t, take.timecodes, f"take {path}")
    return np.minimum(np.round(at), np.floor(at[-1] + 1e-6))


def _column_name(arkit_name: str) -> str:
    """A take's column of an ARKit shape: its name in PascalCase (``jawOpen``: ``JawOpen``)."""
    return arkit_name[0].upper() + arkit_name[1:]


def _edited_text(text: str, before: np.ndarray, after: np.ndarray) -> tuple[str, list[str]]:
    """A take's CSV ``text`` with the fields of each curve whose value ``after`` (F, 52) differs
    from ``before`` (what was read) written anew; every other byte kept (module notes of
    :func:`edit_take`), a quoted field's quotes too. Rows are the header's followers that are
    not empty, records as the reader reads them (a quoted field may hold a line break: before,
    an IndexError, and a row's quotes were dropped). Returns the text and the ARKit names of
    the curves that changed."""
    import csv

    from .arkit import ARKIT_NAMES

    lines = list(StringIO(text, newline=""))      # each with its own line ending
    taken: list[int] = []                         # the lines the csv reader has read

    def fed():
        for k, line in enumerate(lines):
            taken.append(k)
            yield line

    records, start = [], 0
    for fields in csv.reader(fed()):              # each record with its own lines' text
        records.append(("".join(lines[start:len(taken)]), fields))
        start = len(taken)
    header = [h.strip().lower() for h in records[0][1]]
    differs = after != before                          # (F, 52)
    edited = [j for j in range(len(ARKIT_NAMES)) if differs[:, j].any()]
    cols = {j: header.index(_column_name(ARKIT_NAMES[j]).lower()) for j in edited}
    out, row = [records[0][0]], 0
    for raw, fields in records[1:]:
        if fields and differs[row].any():
            raw = _replaced(raw, {cols[j]: f"{after[row, j]:.8f}"
                                  for j in np.flatnonzero(differs[row])})
        row += bool(fields)
        out.append(raw)
    return "".join(out), [ARKIT_NAMES[j] for j in edited]


def _replaced(raw: str, new: dict[int, str]) -> str:
    """The text ``raw`` of a CSV record (its line ending too) with its fields ``new`` (``{index:
    text}``) replaced, every other byte as it was (a quoted field's quotes, ``""`` in it)."""
    body = raw.rstrip("\r\n")
    if '"' not in body:               # the usual record: its fields split at every comma
        fields = body.split(",")
        for c, value in new.items():
            fields[c] = value
        return ",".join(fields) + raw[len(body):]
    starts, quoted = [0], False
    for k, ch in enumerate(raw):
        if ch == '"':
            quoted = not quoted
        elif ch == "," and not quoted:
            starts.append(k + 1)
    ends = [s - 1 for s in starts[1:]] + [len(body)]
    for c in sorted(new, reverse=True):
        raw = raw[:starts[c]] + new[c] + raw[ends[c]:]
    return raw


def _first_timecode(timecodes, fps: float) -> str | None:
    """The first of a take's rows' timecodes as the start timecode (``HH:MM:SS:FF``) of a
    video of ``fps`` frames a second, the rate the take is played at (:func:`take_row_rate`):
    its frame counted at that rate's nominal one, the part of a frame dropped. What a preview
    (``puppet take.csv``) or an export of the take carries, so that it lines up with the plate
    in an editor; None for a take without rows. Before: the label's own frame number, counted
    at the take's timecode rate (:func:`take_rate`): a 25 fps clip's take in the app's labels
    (30 a second) from frame 13 said 15 (``01:00:00:15.600``), and from frame 24 said 28, a
    frame 25 fps has not."""
    if not len(timecodes):
        return None
    f = _timecode_fields(timecodes)
    h, m, sec = (int(v) for v in f[0, :3])
    nominal = max(1, int(round(fps)))     # 30 for 29.97: a timecode counts nominal frames
    frame = (f[0, 3] + f[0, 4] / 1000.0) * nominal / _rate(f, False)
    ff = min(int(np.floor(frame + 1e-6)), nominal - 1)
    return f"{h:02d}:{m:02d}:{sec:02d}:{ff:02d}"


def take_row_rate(seconds: np.ndarray, timecodes, name: str = "the take") -> float:
    """The rate of a take's rows, frames a second (:func:`_rows_rate`; ``seconds``: the rows'
    :func:`take_seconds`): what a preview of it plays them at (``puppet take.csv``), and what
    ``probe`` says beside its timecode rate where they differ (a 25 fps clip's export counts
    30 a second with thousandths, the app's way: its rows are 25 a second)."""
    return _rows_rate(np.asarray(seconds, float), _timecode_fields(timecodes, name))


def _rows_rate(t: np.ndarray, f: np.ndarray) -> float:
    """The frame rate of a take's rows at ``t`` (F,) seconds (parsed timecodes ``f`` (F, 5)):
    the timecode rate whose frame is nearest their median step; of rows in clock time (the
    app's, with sub-frames) at an NTSC rate's true one (``r * 1000 / 1001``) where the rows
    fall on its frames (:func:`_phase`; a 29.97 fps take's rows lie 1001 / 30000 s apart: at
    30 fps its preview drifted 0.6 s in ten minutes)."""
    if t.size < 2:         # one row: the rate its timecode was read at (said, a guess)
        return float(_rate(f, False))
    step = float(np.median(np.diff(t)))
    fps = float(min(TIMECODE_RATES, key=lambda r: abs(1.0 / r - step)))
    if not f[:, 4].any():        # whole frames count frames: the nominal rate
        return fps
    ntsc = fps * 1000.0 / 1001.0
    d = t - t[0]                 # the rate whose frames the rows fall on (a dropped row too)
    return ntsc if _phase(d, ntsc) < _phase(d, fps) else fps


def _phase(d: np.ndarray, rate: float) -> float:
    """The mean distance (in frames) of times ``d`` (seconds) from the frames of ``rate``: ~0
    at the rows' own rate, growing along a take at another (1/1000 of a frame a frame between
    30 and 29.97: the span's frame count alone missed it beyond ~500 rows)."""
    x = d * rate
    return float(np.mean(np.abs(x - np.round(x))))


def take_length(path, max_frames: int | None = None, *, warn: bool = True
                ) -> tuple[int, float]:
    """``(n_frames, fps)`` of the timeline a take is laid out on (:func:`take_track`'s: what
    ``view`` and ``puppet`` of it number, and what a photo as a transfer's target performs it
    over): a frame every ``1 / fps`` seconds from its first row to its last, at the rate of
    its rows (:func:`take_row_rate`), so frame ``k`` is row ``k`` where no row is dropped (a
    dropped row's frame lies between its neighbours); its first ``max_frames``. ``warn``: a
    short take's rate guess said (:func:`take_rate`). TransferError where it is no take, has
    no rows, or its timecodes repeat or go back."""
    take = _load(path)
    _, fps, n = _timeline(take.timecodes, f"take {path}", warn)
    return (n if max_frames is None else max(1, min(n, int(max_frames)))), fps


def _timeline(timecodes, name: str, warn: bool = True) -> tuple[np.ndarray, float, int]:
    """``(seconds, fps, n)``: a take's rows' :func:`take_seconds`, their
    :func:`take_row_rate` and the frames of that rate from the first row to the last
    (:func:`take_length`)."""
    t = take_seconds(timecodes, warn=warn, name=name)
    fps = take_row_rate(t, timecodes, name)
    return t, fps, int(np.floor(t[-1] * fps + 1e-6)) + 1


def take_track(path, model, identity: np.ndarray, *, size: tuple[int, int] = PREVIEW_SIZE,
               max_frames: int | None = None, in_place: bool = False):
    """A take as a track of its own: ``identity`` (the model's identity weights) performing it
    with the take's head rotation, framed in ``size`` (the model's mean face filling 0.6 of
    it, its box as turned on each frame at the centre: :func:`_centred`), at the timecode rate
    nearest the take's rows (``max_frames``: the first ones). ``in_place``: every frame's
    translation the unturned face's instead, the head turning about the model's origin (a
    take holds no head translation: what an export of it carries, not a preview's framing).

    The head's yaw, pitch and roll are the take's ``HeadYaw``, ``HeadPitch``, ``HeadRoll`` in
    radians with the app's signs (:data:`facetransfer.export.livelink.HEAD_SIGNS`: yaw > 0
    toward the subject's right, pitch > 0 looking down, roll > 0 clockwise in the image), taken
    to ``R = Ry(yaw) Rx(pitch) Rz(roll)`` of :func:`facetransfer.export.common.head_euler`'s
    angles (before the review of the fifty-fourth session the take's yaw and roll were taken
    as they are: a real take's head turned the other way). What ``facetransfer puppet take.csv``
    renders: the take seen on a face before it goes into a scene.

    Returns
    -------
    Track
        Its ``source`` the take, its ``source_facts`` first frame 0 and the take's first row's
        timecode in frames of its ``fps`` (:func:`_first_timecode`; what an export of it starts
        from), ``info["start_timecode"]`` the same.
    """
    from scipy.spatial.transform import Rotation

    from .arkit import ARKIT_NAMES, activations_to_weights
    from .export.livelink import HEAD_SIGNS
    from .io.source_facts import SourceFacts
    from .render import look_at_weak_perspective
    from .track.project import project_landmarks
    from .track.result import Track

    take = _read(path, model)
    t, fps, n = _timeline(take.timecodes, f"take {path}")
    start = _first_timecode(take.timecodes, fps)
    n = n if max_frames is None else min(n, int(max_frames))
    rows = take_on_timeline(t, np.hstack([take.activations, take.pose]), n, fps, align="hold")
    a, ypr = np.clip(rows[:, :52], 0.0, 1.0), rows[:, 52:55]
    k = model.mode_index("identity")
    wid = np.asarray(identity, np.float64).ravel()
    mean = model.synthesize(model.default_weights())
    cam = look_at_weak_perspective(mean, size, fill=0.6)
    R = Rotation.from_euler("YXZ", ypr * HEAD_SIGNS).as_matrix()   # the app's signs to ours
    track = Track(fps=fps, frame_size=tuple(size), rotation=R, scale=np.full(n, cam.scale),
                  translation=_centred(mean, np.eye(3)[None].repeat(n, 0) if in_place else R,
                                       cam.scale, size),
                  weights={model.mode_names[k]: np.tile(wid, (n, 1)),
                           "expression": activations_to_weights(model, a)},
                  landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                  lost=np.zeros(n, bool), model_hash=model.content_hash,
                  mode_names=model.mode_names, source=str(path),
                  blendshapes=a.astype(np.float32), blendshape_names=ARKIT_NAMES,
                  source_facts=SourceFacts(0, start))   # its clip's start: the take's
    # the take's start timecode, for its preview, and its recorded eye angles, which the
    # puppet and the view page turn the eyes by (read here: the take is not read again)
    return dataclasses.replace(project_landmarks(track, model), info={
        "start_timecode": start, "eye_gaze": _eye_gaze(take, rows[:, 52:])})


def _eye_gaze(take, pose: np.ndarray) -> np.ndarray | None:
    """``(n, 2, 2)``, the take's recorded eye angles (``RightEyeYaw``, ``RightEyePitch``,
    ``LeftEyeYaw``, ``LeftEyePitch`` of ``pose``, its :data:`facetransfer.export.livelink.
    POSE_COLUMNS` on the track's timeline) as :mod:`facetransfer.track.gaze` has gaze
    (``[frame, eye (right, left), (yaw, pitch)]``, yaw positive toward the subject's left,
    pitch up: the take's yaw is positive toward the subject's right, its pitch looking down,
    :data:`facetransfer.export.livelink.EYE_SIGNS`; before, its yaw was taken as it is and a
    real take's eyes turned the other way); None where the take lacks one of them or they are
    all 0 (a tool that records none): :func:`facetransfer.puppet_face.track_gaze`."""
    from .export.livelink import EYE_SIGNS, POSE_COLUMNS

    names = ("RightEyeYaw", "RightEyePitch", "LeftEyeYaw", "LeftEyePitch")
    if any(n in take.missing for n in names):
        return None
    gaze = pose[:, [POSE_COLUMNS.index(n) for n in names]].reshape(-1, 2, 2)
    if not np.any(gaze):
        return None
    return gaze * EYE_SIGNS


def _centred(vertices: np.ndarray, rotation: np.ndarray, scale: float, size) -> np.ndarray:
    """``(F, 2)`` translations that put the box of ``vertices`` turned by each ``rotation``
    ``(F, 3, 3)`` at the centre of a frame of ``size`` (W, H) at ``scale`` (before: one
    translation, of the unturned face, for every frame: the model turns about its origin, off
    the face, and a turned face was drawn off centre). The box's extremes are among the
    vertices of the convex hull: only those are turned."""
    from scipy.spatial import ConvexHull

    hull = vertices[ConvexHull(vertices).vertices]
    turned = np.einsum("fij,vj->fvi", rotation[:, :2], hull)
    centre = 0.5 * (turned.min(axis=1) + turned.max(axis=1))
    W, H = size
    return np.stack([(W - 1) / 2 - scale * centre[:, 0], (H - 1) / 2 + scale * centre[:, 1]],
                    axis=1)
