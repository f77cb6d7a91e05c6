"""Live Link Face CSV: the take file of Epic Games' Live Link Face iOS app, column for column.

Importers (the Blender, Maya and MotionBuilder add-ons, Unreal's Live Link Face importer) read
its columns by position, so the layout is the app's exactly:

* header ``Timecode,BlendShapeCount,`` then the 52 ARKit names in PascalCase in the app's order
  (:data:`LIVELINK_NAMES`: eyes left, eyes right, jaw, mouth, brows, cheeks, nose, tongue; note
  ``JawRight`` before ``JawLeft`` and ``MouthRight`` before ``MouthLeft``), then the 9 rotation
  columns :data:`POSE_COLUMNS`;
* one row per frame: timecode ``HH:MM:SS:FF.mmm``, the frame's time after its clip's start
  timecode, labelled as the app labels its rows (``labels="app"``, the default of the writers:
  frames of :func:`app_rate`, 30 or 60 a second, with thousandths, which Unreal's Live Link
  Face importer reads right at every clip rate), or as the clip's timecode counts its frames
  (``labels="clip"``: ``FF`` at the nominal integer rate, ``.000``; after a drop-frame start,
  which the CSV cannot say, clock time, ``.mmm`` the thousandths of a frame:
  :func:`format_timecode`), the count
  ``61`` (52 + 9 values), the activations in [0, 1], then head yaw, pitch and roll in **radians**
  (:func:`facetransfer.export.common.head_euler` with the app's signs, :data:`HEAD_SIGNS`: yaw
  positive toward the subject's right, pitch positive looking down, roll positive clockwise
  in the image, the eyes' convention) and the six eye angles in radians, read back
  from the eyeLook* activations (:func:`facetransfer.track.gaze.activation_gaze`: 35° per unit
  of In/Out, 28° of Up/Down, the tracker's own scale) as the app relates them to its curves
  (:data:`EYE_SIGNS`): yaw positive toward the subject's right (``LeftEyeYaw`` rising with
  ``EyeLookInLeft``, ``RightEyeYaw`` with ``EyeLookOutRight``), pitch positive looking down,
  roll 0.

References
----------
Epic's Live Link Face importer for Unreal (``LiveLinkFaceImporterFactory``): the header's
first two names, the rate inferred as 60 where a frame number passes 30 (else 30), a row at
``HH:MM:SS`` plus ``FF.mmm`` over that rate. Header row of the app's CSV takes as reproduced
byte for byte by open importers: nmfisher/blender_livelinkface (``bpylivelinkface.py``,
``LIVE_LINK_FACE_HEADER``), alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder; radians
for the head angles as in JimWest/MeFaMo (Euler angles of the pose matrix sent as
``HeadYaw``/``HeadPitch``/``HeadRoll``); the eye angles' units and signs as in three takes the
app wrote (MySlate_1_iPhone.csv of dwskillman/BlendFiles, anim/alex_rom_3.csv and
alex_rom_4.csv of alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder; 679, 4030 and 3809
rows): ``LeftEyeYaw`` against ``EyeLookInLeft - EyeLookOutLeft`` has slope +0.59 to +0.61
radians a unit, ``RightEyeYaw`` against ``EyeLookInRight - EyeLookOutRight`` -0.59 to -0.61,
each eye's pitch against ``EyeLookDown - EyeLookUp`` +0.54 to +0.61 (radians: ±0.6 is 34°;
the eyes' ±0.6 could not be the ±108° of degrees / 180); ``tests/test_export_conventions.py``.
Those takes record the head as 0; the head's signs follow from the eyes' (:data:`HEAD_SIGNS`):
Unreal's ARKit face support (``AppleARKitFaceMeshConversion.h``, ``ToBlendShapeMap``) turns the
face anchor's rotation and each eye's into ``HeadYaw/Pitch/Roll`` and ``LeftEyeYaw/...`` by one
rule (yaw and roll negated together, pitch kept), and ARKit's face anchor, in its mirrored
face-tracking world, has the eyes' axes (Apple's ``ARFaceAnchor``: x to the face's own left,
y up, z out of the face; identity facing the camera), so a head and eyes turned the same way
have the same signs; JimWest/MeFaMo, written to stand in for the app, sends ``HeadYaw`` and
``HeadRoll`` negated from its pose matrix's (MediaPipe's canonical face, the same axes) and
``HeadPitch`` as it is. Before the review of the fifty-fourth session the head's yaw and roll
were written with our signs (``head_euler``'s): turned against the app's.
"""

from __future__ import annotations

import csv
import io
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..arkit import ARKIT_NAMES
from ..io.atomic import write_text_atomic
from .common import ExportError, head_euler, require_activations

__all__ = ["LIVELINK_NAMES", "POSE_COLUMNS", "EYE_SIGNS", "HEAD_SIGNS", "HEADER", "LABELS", "DEFAULT_LABELS",
           "app_rate", "format_timecode", "parse_timecode",
           "timecode_fields", "source_timecode",
           "livelink_rows", "eye_angles", "write_livelink", "read_livelink", "LiveLinkTake"]

#: The app's 52 blendshape columns, in its order.
LIVELINK_NAMES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft",
    "EyeSquintLeft", "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight",
    "EyeLookOutRight", "EyeLookUpRight", "EyeSquintRight", "EyeWideRight", "JawForward",
    "JawRight", "JawLeft", "JawOpen", "MouthClose", "MouthFunnel", "MouthPucker", "MouthRight",
    "MouthLeft", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft", "MouthFrownRight",
    "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft",
    "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft",
    "MouthUpperUpRight", "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft",
    "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft",
    "NoseSneerRight", "TongueOut",
)
#: ``(yaw, pitch)`` of an eye column = these signs times :mod:`facetransfer.track.gaze`'s
#: angles: in the app's takes (module notes, References) an eye's yaw is positive toward the
#: subject's right and its pitch looking down; gaze's yaw is toward the subject's left, up.
EYE_SIGNS = np.array([-1.0, -1.0])
#: ``(HeadYaw, HeadPitch, HeadRoll)`` = these signs times
#: :func:`facetransfer.export.common.head_euler`'s (yaw toward the image's right, pitch down,
#: roll counter-clockwise): the app's yaw is positive toward the subject's right (the image's
#: left), as its eyes' yaw, and its roll clockwise in the image (module notes, References).
HEAD_SIGNS = np.array([-1.0, 1.0, -1.0])
#: The 9 rotation columns after the blendshapes (radians).
POSE_COLUMNS: tuple[str, ...] = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw",
                                 "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch",
                                 "RightEyeRoll")
HEADER: tuple[str, ...] = ("Timecode", "BlendShapeCount") + LIVELINK_NAMES + POSE_COLUMNS
#: Position in :data:`ARKIT_NAMES` of each app column (PascalCase = capitalised camelCase).
_TO_ARKIT = np.array([ARKIT_NAMES.index(n[0].lower() + n[1:]) for n in LIVELINK_NAMES])
if sorted(_TO_ARKIT.tolist()) != list(range(len(ARKIT_NAMES))):  # a packaging error
    raise ImportError("LIVELINK_NAMES is not a permutation of ARKIT_NAMES")

#: A take's timecode: ``HH:MM:SS:FF.mmm`` as the app writes it; other tools' without the
#: thousandths, or ``;`` before the frames of a drop-frame one.
_TC = re.compile(r"^(\d{2,}):(\d{2}):(\d{2})[:;](\d{2,3})(?:\.(\d{1,3}))?$")


#: How a take's rows are labelled (:func:`format_timecode`): ``clip``, the clip's own timecode;
#: ``app``, the Live Link Face app's frames of 30 or 60 a second (Unreal's importer).
LABELS: tuple[str, ...] = ("clip", "app")
#: The labels of a take written without ``labels`` said (``export --take-rate``'s default;
#: before, ``clip``). ``batch export``'s job digest names the labels a take is written with.
DEFAULT_LABELS = "app"


def _nominal_rate(fps: float) -> int:
    return max(1, int(round(float(fps))))


def app_rate(fps: float) -> int:
    """The frames a second the Live Link Face app counts its timecodes in, and so the only ones
    Unreal's Live Link Face importer reads a take's ``FF.mmm`` at: 30 for a clip of up to 30
    frames a second (nominal, ``round(fps)``), else 60. The importer takes 60 where a row's
    frame number passes 30, else 30; a row's time is then ``HH:MM:SS`` plus ``FF.mmm`` over
    that rate."""
    return 30 if _nominal_rate(fps) <= 30 else 60


def format_timecode(frame: int, fps: float, start: str | None = None, *,
                    labels: str = "clip") -> str:
    """``HH:MM:SS:FF.mmm`` of frame ``frame`` of a clip at ``fps`` whose first frame is
    ``start`` (``HH:MM:SS:FF``, ``;`` before the frames of a drop-frame one; default
    ``00:00:00:00``).

    ``labels="clip"`` (default): counted as the clip's timecode counts its frames
    (:func:`facetransfer.io.plate_header.timecode_after`, at the nominal rate ``round(fps)``;
    ``.000``): the take lines up with its
    plate frame for frame (a 23.976 fps plate's frame 1000 after ``01:00:00:00`` is
    ``01:00:41:16``). The CSV has no drop-frame notation, so after a drop-frame start the rows
    count clock time instead: ``start``'s moment plus ``frame / fps`` seconds in frames of the
    nominal rate, ``.mmm`` the thousandths of a frame (``01:00:00;00`` at 29.97 fps is
    ``00:59:59:29.892``).

    ``labels="app"``: as the Live Link Face app writes them, in frames of :func:`app_rate` (30
    or 60) a second with thousandths: ``start``'s moment plus ``frame / fps`` seconds (frame 1
    of a 25 fps clip is ``00:00:00:01.200``), which Unreal's Live Link Face importer places at
    ``frame / fps`` seconds whatever the clip's rate. A clip at 30 or 60 (or 29.97, 59.94)
    frames a second has the same labels either way.
    """
    from ..io.plate_header import timecode_after, timecode_count

    if labels not in LABELS:
        raise ExportError(f"labels must be one of {', '.join(LABELS)}, got {labels!r}")
    start = start or "00:00:00:00"
    try:
        count, drop = timecode_count(start, fps)
    except ValueError as exc:
        raise ExportError(f"start timecode: {exc}") from None
    rate = _nominal_rate(fps)
    if not drop and (labels == "clip" or rate == app_rate(fps)):
        label = timecode_after(start, int(frame), fps)
        return label[:8] + ":" + label[9:] + ".000"
    moment = count / (rate * 1000.0 / 1001.0 if drop else rate)   # the start's, seconds
    per = rate if labels == "clip" else app_rate(fps)              # the labels' frames a second
    units = round((moment + int(frame) / float(fps)) * per * 1000)
    whole, milli = divmod(units, 1000)
    secs, ff = divmod(whole, per)
    mins, ss = divmod(secs, 60)
    hh, mm = divmod(mins, 60)
    return f"{hh % 24:02d}:{mm:02d}:{ss:02d}:{ff:02d}.{milli:03d}"


def timecode_fields(timecodes) -> np.ndarray:
    """``(F, 5)`` int: hours, minutes, seconds, frame and thousandths of a frame of each
    timecode (:data:`_TC`; thousandths 0 where a timecode has none)."""
    out = []
    for t in timecodes:
        m = _TC.match(str(t).strip())
        if m is None:
            raise ExportError(f"timecode {t!r} is not HH:MM:SS:FF.mmm")
        hh, mm, ss, ff, milli = m.groups()
        out.append((int(hh), int(mm), int(ss), int(ff), int((milli or "0").ljust(3, "0"))))
    return np.array(out, np.int64).reshape(-1, 5)


def parse_timecode(text: str, fps: float) -> float:
    """Frames since ``00:00:00:00`` of a ``HH:MM:SS:FF.mmm`` timecode counted at the nominal
    rate ``round(fps)`` (thousandths: a fraction of a frame); the inverse of
    :func:`format_timecode` from ``00:00:00:00``."""
    hh, mm, ss, ff, milli = (int(v) for v in timecode_fields([text])[0])
    rate = _nominal_rate(fps)
    return ((hh * 60 + mm) * 60 + ss) * rate + ff + milli / 1000.0


def livelink_rows(track, start: str | None = None, *, labels: str = "app") -> list[list[str]]:
    """The CSV as rows of strings (header first); ``start``: the first row's timecode,
    ``labels``: how the rows' timecodes count (:func:`format_timecode`)."""
    acts = require_activations(track)             # (F, 52) in ARKIT_NAMES order
    a = acts[:, _TO_ARKIT]                        # in the app's order
    ypr = head_euler(track.rotation) * HEAD_SIGNS  # (F, 3) radians, the app's signs
    pose = np.zeros((track.n_frames, len(POSE_COLUMNS)))
    pose[:, :3] = ypr
    pose[:, 3:] = eye_angles(acts)
    count = str(len(LIVELINK_NAMES) + len(POSE_COLUMNS))
    rows = [list(HEADER)]
    for k in range(track.n_frames):
        rows.append([format_timecode(k, track.fps, start, labels=labels), count]
                    + [f"{v:.8f}" for v in a[k]] + [f"{v:.8f}" for v in pose[k]])
    return rows


def eye_angles(activations: np.ndarray) -> np.ndarray:
    """``LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, RightEyePitch, RightEyeRoll`` in
    radians, ``(F, 6)``, from the (F, 52) activations' eyeLook* (module notes): yaw positive
    toward the subject's right, pitch positive looking down (:data:`EYE_SIGNS`), as the app's
    takes have them (before, the yaw was turned: positive toward the subject's left)."""
    from ..track.gaze import activation_gaze

    g = activation_gaze(activations) * EYE_SIGNS   # (F, eye (right, left), (yaw, pitch))
    out = np.zeros((len(g), 6))
    for col, k in ((0, 1), (3, 0)):            # the subject's left eye first, as the app
        out[:, col:col + 2] = g[:, k]
    return out


def write_livelink(track, out: str | os.PathLike, *, overwrite: bool = False,
                   start: str | None = None, labels: str = "app") -> Path:
    """Write the track as a Live Link Face CSV take (atomically) and return the path;
    ``start``: its first row's timecode, ``HH:MM:SS:FF`` (its video's start timecode; default
    ``00:00:00:00``), each row after it a frame later as the app counts (``labels="app"``,
    the default: what Unreal's importer reads right) or as the video's timecode counts
    (``"clip"``; :func:`format_timecode`)."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(livelink_rows(track, start, labels=labels))
    return write_text_atomic(out, buf.getvalue(), overwrite=overwrite)


@dataclass(frozen=True)
class LiveLinkTake:
    """A Live Link Face CSV read back.

    Attributes
    ----------
    timecodes : tuple of str
    activations : (F, 52) float64
        In :data:`facetransfer.arkit.ARKIT_NAMES` order, as the take holds them (the app's
        pass 1 a little at the extremes: up to :data:`ACTIVATION_MAX`).
    pose : (F, 9) float64
        :data:`POSE_COLUMNS`, radians.
    missing : tuple of str
        Columns the file lacks, read as 0 (``lenient`` reading only).
    """

    timecodes: tuple[str, ...]
    activations: np.ndarray
    pose: np.ndarray
    missing: tuple[str, ...] = ()

    def frames(self, fps: float) -> np.ndarray:
        """Every row's timecode as frames since ``00:00:00:00`` at the nominal rate
        ``round(fps)`` (:func:`parse_timecode`; a row of an export of a clip at ``fps`` is its
        frame's count), ``(F,) float64``."""
        return np.array([parse_timecode(t, fps) for t in self.timecodes])


def read_livelink(path: str | os.PathLike, *, lenient: bool = False) -> LiveLinkTake:
    """Read a Live Link Face CSV (columns by name; the app's header is required).

    ``lenient``: takes written by other tools, too: names matched whatever their case
    (``eyeBlinkLeft``), timecodes without thousandths, and columns missing (the eyes' roll,
    ``TongueOut``, a tool's fewer shapes) read as 0 and listed in
    :attr:`LiveLinkTake.missing`; at least one blendshape column is needed.
    """
    p = Path(path)
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark
            rows = list(csv.reader(fh))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ExportError(f"{p} is not a Live Link Face CSV (not UTF-8 text: {exc})") from None
    if not rows:
        raise ExportError(f"{p} is empty, not a Live Link Face CSV (its header starts "
                          "'Timecode,BlendShapeCount')")
    if [c.strip().lower() for c in rows[0][:2]] != ["timecode", "blendshapecount"]:
        raise ExportError(f"{p} is not a Live Link Face CSV (header must start "
                          f"'Timecode,BlendShapeCount')")
    key = (lambda n: n.strip().lower()) if lenient else (lambda n: n)
    col = {key(n): i for i, n in enumerate(rows[0])}
    names = [key(n) for n in rows[0]]
    twice = sorted(n for n in {key(m) for m in LIVELINK_NAMES + POSE_COLUMNS}
                   if names.count(n) > 1)
    if twice:       # which of the two is meant cannot be told: one would silently win
        raise ExportError(f"{p} names the column {rows[0][names.index(twice[0])].strip()} "
                          "twice")
    missing = [n for n in LIVELINK_NAMES + POSE_COLUMNS if key(n) not in col]
    if missing and (not lenient or all(n in missing for n in LIVELINK_NAMES)):
        raise ExportError(f"{p} lacks the columns {missing[:5]}")
    body = [(line, r) for line, r in enumerate(rows[1:], start=2) if r]
    for line, r in body:
        if len(r) < len(rows[0]):
            raise ExportError(f"{p} line {line} has {len(r)} fields, its header {len(rows[0])}")
        if _TC.match(r[0].strip()) is None:
            raise ExportError(f"{p} line {line}: timecode {r[0]!r} is not HH:MM:SS:FF.mmm")
    a = _take_values(p, rows[0], body, [col.get(key(n)) for n in LIVELINK_NAMES])
    pose = _take_values(p, rows[0], body, [col.get(key(n)) for n in POSE_COLUMNS])
    _check_unit(p, rows[0], body, a, [col.get(key(n)) for n in LIVELINK_NAMES])
    act = np.zeros_like(a)
    act[:, _TO_ARKIT] = a
    return LiveLinkTake(tuple(r[0].strip() for _, r in body), act, pose, tuple(missing))


def _take_values(p: Path, header: list, body: list, cols: list) -> np.ndarray:
    """``(rows, len(cols))`` float64 of the fields ``cols`` (None: a missing column, 0) of
    each ``(line, fields)`` of ``body``; ExportError naming the file, line and column of a
    field that is not a finite number."""
    try:
        out = np.array([[float(r[c]) if c is not None else 0.0 for c in cols] for _, r in body],
                       np.float64).reshape(-1, len(cols))
        if np.isfinite(out).all():
            return out
    except ValueError:
        pass
    for line, r in body:      # the first field that is no finite number, named
        for c in cols:
            try:
                ok = c is None or bool(np.isfinite(float(r[c])))
            except ValueError:
                ok = False
            if not ok:
                raise ExportError(f"{p} line {line}, column {header[c].strip()}: {r[c]!r} is "
                                  "not a finite number")
    raise AssertionError("unreachable: a field failed, then none did")  # pragma: no cover


#: The largest blendshape value a take may hold: ARKit's coefficients pass 1 a little at the
#: extremes, and the app writes them as they come (its takes, module notes: eyeLookIn up to
#: 1.053 in 91 of alex_rom_4's 3809 rows; a take refused for it before the fifty-fourth
#: session). Above it a column is no activation (a percentage, an angle): refused.
ACTIVATION_MAX = 1.25


def _check_unit(p: Path, header: list, body: list, a: np.ndarray, cols: list) -> None:
    """ExportError naming the first blendshape value of ``a`` (rows, 52) outside
    0..:data:`ACTIVATION_MAX` (a thousandth of slack below 0): Live Link Face's are
    activations. Values over 1 are kept as the take holds them; what a take drives clips
    them to 0..1."""
    bad = np.argwhere((a < -1e-3) | (a > ACTIVATION_MAX))
    if bad.size:
        i, j = bad[0]
        line, r = body[i]
        raise ExportError(f"{p} line {line}, column {header[cols[j]].strip()}: "
                          f"{r[cols[j]]} is outside 0..1 (a blendshape's activation; the "
                          f"app's pass 1 by a few hundredths at most)")


def source_timecode(track) -> str | None:
    """The start timecode of the video a track was made from
    (:func:`facetransfer.io.video_display.timecode_of`: a video file's, a DPX or OpenEXR
    plate's first frame's), as the track records it, else (an older track) read from its
    ``source`` where that is still its clip (:func:`facetransfer.export.common.clip_facts`);
    None without one. A take exported with it lines up with that video."""
    from .common import clip_facts

    return clip_facts(track)[0].timecode
