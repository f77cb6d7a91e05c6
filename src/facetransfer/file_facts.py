"""What a track file or a Live Link Face take holds, for ``facetransfer probe``.

``probe`` says how a video is read (:mod:`facetransfer.io.video_facts`); handed a track
(``TRACK.npz``, from ``track``, ``edit`` or ``transfer --save-track``) or a take (``take.csv``,
from the Live Link Face app or ``export --format livelink``), it says what an animator asks of
them before using one: how many frames, at what rate and from what timecode; for a track, the
video and model it was made from, whether it carries ARKit activations, where the face was
lost; for a take, which of the 52 shapes and the head's and eyes' rotations it has.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["file_kind", "track_facts", "take_facts", "file_fact_lines", "lost_runs",
           "covered_note"]

#: What ``probe`` describes, said when it is handed something else (a model is not described:
#: ``probe M.npz`` points to ``model info``; this said "tracks, models and ...").
PROBE_DESCRIBES = ("probe describes videos, image sequences, tracks and Live Link Face takes "
                   "(a model: `facetransfer model info`)")

#: Keys every track file holds (:meth:`facetransfer.track.result.Track.save`).
_TRACK_KEYS = frozenset({"fps", "frame_size", "rotation", "model_hash", "mode_names"})


def file_kind(path: str | os.PathLike) -> str:
    """``"take"`` (a ``.csv``), ``"track"`` (an ``.npz`` with a track's arrays), ``"model"``
    (an ``.npz`` with a model's) or ``"video"`` (anything else: a video or an image sequence,
    for :mod:`facetransfer.io.video_facts`); FaceTransferError for another archive, or for one
    of the tool's exports (glb, USD, JSON, a page), named."""
    from .take import is_take

    from .errors import FaceTransferError
    from .io.npz import NOT_ARCHIVE_ERRORS, archive_names, check_input_file, content_kind, reason

    p = Path(path)
    if p.suffix.lower() in (".npz", ".csv"):    # before: "video X.npz does not exist"
        check_input_file(p, "take" if is_take(p) else "track or model file")
    if is_take(p):
        return "take"
    if p.suffix.lower() == ".npz" and p.is_file():
        try:
            names = archive_names(p)
        except NOT_ARCHIVE_ERRORS as exc:
            raise FaceTransferError(f"{p} is truncated or not an .npz archive "
                                    f"({reason(exc)})") from None
        if names is None:   # an .npy named .npz (was TypeError)
            raise FaceTransferError(f"{p} is a single .npy array, not an .npz archive: "
                                    + PROBE_DESCRIBES)
        if _TRACK_KEYS <= names:
            return "track"
        if {"core", "metadata"} <= names:
            return "model"
        raise FaceTransferError(f"{p} is an .npz archive of {_other_npz(p, names)}, not a track "
                                "or a model: " + PROBE_DESCRIBES)
    kind = content_kind(p) if p.is_file() else None
    if kind is not None and kind.startswith(("a glTF", "a USD", "a JSON", "an HTML")):
        # one of the tool's own exports: said so, not "not a video OpenCV can decode"
        raise FaceTransferError(f"{p} is {kind}: " + PROBE_DESCRIBES)
    return "video"


def _other_npz(p: Path, names: set) -> str:
    """What the .npz archive ``p`` of array ``names``, no track or model, holds."""
    from .io.npz import known_npz

    known = known_npz(p, names)
    if known is not None:
        return known
    shown = sorted(names)
    return "arrays " + ", ".join(shown[:6]) + (", ..." if len(shown) > 6 else "") \
        if shown else "no arrays"


def lost_runs(lost: np.ndarray, first: int = 0) -> str:
    """``"3-7, 12"``: a track's lost frames as runs (the first four), counted from ``first``
    (a plate's first frame number: :func:`facetransfer.io.frame_numbers.frame_runs`)."""
    from .io.frame_numbers import frame_runs

    return frame_runs(lost, first)


def covered_note(track, first: int = 0) -> str:
    """What ``track --occluders`` (and ``batch track --occluders``, in a clip's ``note``) says
    of a track it tested (:func:`facetransfer.track.occlusion.with_occluders`): the frames
    each region was found covered in, none, or why it was not tested (``occluded`` None: fewer
    frames than a run); a plate's frames by their numbers, from ``first``."""
    from .track.occlusion import MIN_RUN, REGIONS

    if track.occluded is None:
        n = track.n_frames
        return (f"not tested for a covered mouth or eye: {n} frame{'' if n == 1 else 's'}, "
                f"and the test compares {MIN_RUN} frames or more with the clip's own")
    said = [f"{name.replace('_', ' ')} in frames {lost_runs(track.occluded[:, r], first)}"
            for r, name in enumerate(REGIONS) if track.occluded[:, r].any()]
    held = ("the activations of each bridged there" if track.blendshapes is not None else
            "recorded: the model has no ARKit activations to bridge")
    return f"covered: {'; '.join(said)} ({held})" if said else "no mouth or eye found covered"


def _no_activations(f: dict) -> str:
    """Why a track (its :func:`track_facts` ``f``) holds no activations."""
    if f["default_model"]:      # an optical-flow track written before they were attached
        return "none (written by an older version: track the video again to export it)"
    return ("none (the model's expressions are not ARKit-named, or an optical-flow track "
            "written by an older version: nothing to export)")


def _default_model_hash() -> str | None:
    """The content hash of the default model if it is built (read from its file's metadata,
    not by loading it), else None."""
    from .default_model import default_model_path, stated_hash

    return stated_hash(default_model_path())


def track_facts(path: str | os.PathLike) -> dict:
    """What the track file ``path`` holds, as a JSON-ready dict (TrackError for a file that is
    not one)."""
    from .export.livelink import source_timecode
    from .track.result import Track

    from .io.frame_numbers import track_first_number

    t = Track.load(path)
    n, first = t.n_frames, track_first_number(t)    # a plate's frames by its numbers
    default = _default_model_hash()
    return {
        "kind": "track", "path": str(path), "frames": n, "fps": float(t.fps),
        "seconds": n / float(t.fps) if t.fps else 0.0, "frame_size": list(t.frame_size),
        "pixel_aspect": float(t.pixel_aspect), "source": t.source or None,
        "source_timecode": source_timecode(t), "model_hash": t.model_hash,
        "default_model": None if default is None else t.model_hash == default,
        "modes": list(t.mode_names),
        "activations": None if t.blendshapes is None else len(t.blendshape_names or ()),
        "first_frame": first,
        "lost_frames": int(np.count_nonzero(t.lost)), "lost": lost_runs(t.lost, first),
        "mean_confidence": float(np.mean(t.confidence)) if n else 0.0,
        "shots": [first + s for s in (0, *t.shot_starts)],
        "neutral_frame": None if t.info.get("neutral_frame") is None else
        first + int(t.info["neutral_frame"]),
        "made_by": t.made_by or None}


def take_facts(path: str | os.PathLike) -> dict:
    """What the Live Link Face take ``path`` holds, as a JSON-ready dict (ExportError or
    TransferError for a file that is not one)."""
    from .export.livelink import LIVELINK_NAMES, POSE_COLUMNS, read_livelink
    from .take import take_rate, take_row_rate, take_seconds

    take = read_livelink(path, lenient=True)
    tc = take.timecodes
    seconds = take_seconds(tc, name=f"take {path}") if tc else np.zeros(0)
    shapes = [n for n in LIVELINK_NAMES if n not in take.missing]
    head = [n for n in POSE_COLUMNS if n.startswith("Head")]
    eyes = [n for n in POSE_COLUMNS if not n.startswith("Head")]
    return {
        "kind": "take", "path": str(path), "rows": len(tc),
        "timecode_rate": take_rate(tc, warn=False) if tc else None,  # said once, above
        "row_rate": take_row_rate(seconds, tc, f"take {path}") if len(tc) > 1 else None,
        "seconds": float(seconds[-1] - seconds[0]) if len(seconds) else 0.0,
        "first_timecode": tc[0] if tc else None, "last_timecode": tc[-1] if tc else None,
        "shapes": len(shapes), "missing_shapes": [n for n in LIVELINK_NAMES if n not in shapes],
        "head_rotation": [n for n in head if n not in take.missing],
        "eye_rotation": [n for n in eyes if n not in take.missing]}


def _columns(present: list, prefix: str) -> str:
    """``"yes"`` where a take holds every rotation column of ``prefix``, ``"none"`` where it
    holds none, else the ones it holds and those read as 0 (``"HeadYaw, HeadPitch (HeadRoll
    read as 0)"``: the ones it holds are used, so "no" would not be true)."""
    from .export.livelink import POSE_COLUMNS

    every = [n for n in POSE_COLUMNS if n.startswith(prefix)]
    if len(present) == len(every):
        return "yes"
    if not present:
        return "none"
    return (", ".join(present) + " (" + ", ".join(n for n in every if n not in present)
            + " read as 0)")


def _count(n: int, word: str) -> str:
    """``"1 frame"``, ``"30 frames"``."""
    return f"{n} {word}" + ("" if n == 1 else "s")


def _track_lines(f: dict) -> list[str]:
    from .io.frame_numbers import frame_span

    w, h = f["frame_size"]
    model = {True: "the default model (ict-arkit)", False: "another model than the default",
             None: "a model"}[f["default_model"]]
    first = f.get("first_frame") or 0      # a plate's: its frames named by their numbers
    lines = [f"{f['path']}: a track of {_count(f['frames'], 'frame')}"
             + (f" (numbered {frame_span(first, f['frames'])}, as the plate's files)" if first
                else "") + f" at {f['fps']:g} fps "
             f"({f['seconds']:.2f} s), {w}x{h}"
             + (f" (pixel aspect {f['pixel_aspect']:g})" if f["pixel_aspect"] != 1 else ""),
             f"  made from: {f['source'] or 'an unnamed video'}"
             + (f", start timecode {f['source_timecode']}" if f["source_timecode"] else "")
             + f"; with {model}, hash {f['model_hash'][:12]}... (modes "
             f"{', '.join(f['modes'])})",
             "  ARKit activations: " + (f"{f['activations']} (exports and takes use them)"
                                        if f["activations"] else _no_activations(f)),
             f"  face lost in {f['lost_frames']} of {f['frames']} frames"
             + (f" ({f['lost']})" if f["lost"] else "")
             + f"; mean confidence {f['mean_confidence']:.2f}"]
    if len(f["shots"]) > 1:
        lines.append(f"  {len(f['shots'])} shots, from frames {', '.join(map(str, f['shots']))}")
    if f["neutral_frame"] is not None:
        lines.append(f"  activations measured from the neutral frame {f['neutral_frame']}")
    if f.get("made_by"):
        lines.append(_made_by_line(f["made_by"]))
    return lines


def _made_by_line(made_by: str) -> str:
    """What a track file marked as a performance (:attr:`facetransfer.track.Track.made_by`)
    is for: ``--performance``, ``export``, ``view``, ``puppet``; not a clip's own track."""
    from .track.result import made_by_words

    return (f"  {made_by_words(made_by)}: give it as --performance, or to export, view, puppet; not a track of "
            "the clip it was made from (refused as --target-track)")


def _take_lines(f: dict) -> list[str]:
    rate = f"{f['timecode_rate']} fps timecode" if f["timecode_rate"] else "no rows"
    rows = f.get("row_rate")
    if rows and abs(rows - f["timecode_rate"]) > 1e-6:   # an export's at the app's count
        rate += f", rows {rows:.3f}".rstrip("0").rstrip(".") + " a second"
    lines = [f"{f['path']}: a Live Link Face take of {_count(f['rows'], 'row')} ({rate})"
             + (f", from {f['first_timecode']} to {f['last_timecode']} ({f['seconds']:.2f} s "
                "apart)" if f["first_timecode"] else ""),
             f"  shapes: {f['shapes']} of 52"
             + (f" (missing, read as 0: {', '.join(f['missing_shapes'])})"
                if f["missing_shapes"] else ""),
             "  head rotation: " + _columns(f["head_rotation"], "Head")
             + "; eye rotation: " + (", ".join(f["eye_rotation"]) or "none")]
    return lines


def file_fact_lines(f: dict) -> list[str]:
    """:func:`track_facts` or :func:`take_facts` as a few lines for a person."""
    return _track_lines(f) if f["kind"] == "track" else _take_lines(f)
