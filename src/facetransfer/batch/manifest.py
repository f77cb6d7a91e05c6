"""The jobs of a batch run: clips, transfer pairs and tracks to export, read from the command
line or a CSV manifest.

A manifest is a CSV file with a header row. Paths in it are relative to the manifest's folder
(absolute paths are kept); an empty cell is an absent value. Every job has a *name*: the ``name``
column if present, else the stem of its main file. The name is the output's file name
(``DIR/NAME.npz``, ``DIR/NAME.mp4``...), so two jobs with the same name are refused before
anything runs.

==================  =========================================================================
manifest            columns
==================  =========================================================================
clips (``track``)   ``video`` (required), ``name``, ``init`` (POINTS.json; default ``auto``),
                    ``face`` (of several people, the one to track, as ``track --face``),
                    ``max_frames`` (track only the clip's first N frames, as
                    ``track --max-frames``), ``occluders`` (``yes``/``no``: test it for a
                    covered mouth or eye, as ``track --occluders``)
pairs (``transfer``) ``target`` (required), ``name``, the sources of ``facetransfer transfer``:
                    ``expression_from``, ``viseme_from``, ``identity_from``, ``pose_from``,
                    ``performance``, their track files ``target_track``, ``source_track``,
                    ``viseme_track``, ``identity_track``, ``pose_track``,
                    ``identity_label`` / ``identity_weights``, and ``target_face`` /
                    ``source_face`` (as ``transfer --target-face`` / ``--source-face``)
==================  =========================================================================
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import FaceTransferError

__all__ = ["BatchError", "ClipJob", "PairJob", "ExportJob", "read_manifest", "clip_jobs",
           "pair_jobs", "export_jobs", "check_unique_names", "CLIP_COLUMNS", "PAIR_PATH_COLUMNS",
           "PAIR_VALUE_COLUMNS"]


class BatchError(FaceTransferError):
    """A batch run cannot start: a bad manifest, duplicate names, a bad cluster or output."""


#: Columns of a clips manifest (``video`` required).
CLIP_COLUMNS = ("video", "name", "init", "face", "max_frames", "occluders")
#: Columns of a pairs manifest holding paths (``target`` required).
PAIR_PATH_COLUMNS = ("target", "expression_from", "viseme_from", "identity_from", "pose_from",
                     "performance", "target_track", "source_track", "viseme_track",
                     "identity_track", "pose_track")
#: Columns of a pairs manifest holding values (not paths).
PAIR_VALUE_COLUMNS = ("name", "identity_label", "identity_weights", "target_face",
                      "source_face")
#: The source columns of which a pair needs at least one (as ``transfer`` does).
PAIR_SOURCES = ("expression_from", "viseme_from", "identity_from", "pose_from", "performance",
                "identity_label", "identity_weights")


class _Job:
    """What every job (:class:`ClipJob`, :class:`PairJob`, :class:`ExportJob`) derives from its
    ``roles``, the input files by what they are to it."""

    @property
    def inputs(self) -> tuple[Path, ...]:
        """The input files: the paths of ``roles``, in their order."""
        return tuple(p for _, p in self.roles)


@dataclass(frozen=True)
class ClipJob(_Job):
    """One clip to track: ``DIR/NAME.npz`` from ``video``.

    Attributes
    ----------
    name : str
    video : str
        As given (recorded as the track's ``source``, as ``facetransfer track`` does).
    init : str
        ``"auto"`` or the path of a POINTS.json for the clip's first frame.
    face : str or None
        Of several people, the one to track (``"left"``, ``"right"``, ``"centre"``, ``"X,Y"``:
        :func:`facetransfer.track.face_crop.subject_point`); None: the face found first.
    max_frames : int or None
        Track only the clip's first ``max_frames`` frames (``track --max-frames``); None: all.
    occluders : bool
        Test the tracked clip for a covered mouth or eye and bridge the covered region's
        activations (``track --occluders``, :func:`facetransfer.track.occlusion.
        with_occluders`). Not in the ``repr``, which the digest of the format before hashed
        (:func:`.digest.legacy_job_key`: its summaries' outputs stay this version's jobs').
    """

    name: str
    video: str
    init: str = "auto"
    face: str | None = None
    max_frames: int | None = None
    occluders: bool = field(default=False, repr=False)

    @property
    def roles(self) -> tuple[tuple[str, Path], ...]:
        """The input files by what they are to the job (``video``, ``init``)."""
        return (("video", Path(self.video)),) + (() if self.init == "auto"
                                                 else (("init", Path(self.init)),))

    @property
    def labels(self) -> tuple[tuple[str, object], ...]:
        """What else makes the job's output: its name, face and frame limit, and
        ``occluders`` where asked (a job without it keeps the digest it had before)."""
        return (("name", self.name), ("face", self.face), ("max_frames", self.max_frames)) + (
            (("occluders", True),) if self.occluders else ())


@dataclass(frozen=True)
class PairJob(_Job):
    """One transfer: ``DIR/NAME.mp4`` rewritten from ``target`` and its sources.

    Attributes
    ----------
    name : str
    target : Path
    sources : dict column -> str
        The manifest's other non-empty cells (paths resolved), keyed by column name.
    """

    name: str
    target: Path
    sources: dict = field(default_factory=dict)

    @property
    def roles(self) -> tuple[tuple[str, Path], ...]:
        """The input files by their columns (``target``, ``expression_from``...)."""
        return (("target", Path(self.target)),) + tuple(
            (k, Path(v)) for k, v in self.sources.items() if k in PAIR_PATH_COLUMNS)

    @property
    def labels(self) -> tuple[tuple[str, object], ...]:
        """What else makes the job's output: its name and value columns, in column order."""
        return (("name", self.name),) + tuple(
            (k, self.sources[k]) for k in PAIR_VALUE_COLUMNS if k in self.sources)


@dataclass(frozen=True)
class ExportJob(_Job):
    """One track file to export as ``DIR/NAME.<ext>``."""

    name: str
    track: Path

    @property
    def roles(self) -> tuple[tuple[str, Path], ...]:
        """The input file: ``track``."""
        return (("track", Path(self.track)),)

    @property
    def labels(self) -> tuple[tuple[str, object], ...]:
        return (("name", self.name),)


def _resolve(value: str, base: Path) -> str:
    """A manifest's path, absolute: against the manifest's folder, then the current one (a
    worker of a real scheduler runs in its own folder: before, a relative path was looked up
    there, and a rerun from another folder took every output for another job's)."""
    p = Path(os.path.expanduser(value))
    return os.path.abspath(p if p.is_absolute() else base / p)


def absolute(value) -> str:
    """A path given on the command line, absolute (:func:`_resolve`'s reason)."""
    return os.path.abspath(os.path.expanduser(str(value)))


#: The key of each row's line in the file (:func:`read_manifest`), for messages.
LINE = "__line__"


def read_manifest(path: str | os.PathLike, *, required: tuple[str, ...],
                  allowed: tuple[str, ...], paths: tuple[str, ...]) -> list[dict[str, str]]:
    """Read a CSV manifest into one dict per row (empty cells dropped, paths resolved and
    absolute, the row's line in the file under :data:`LINE`).

    Parameters
    ----------
    path : path-like
    required : tuple of str
        Columns that must be present and non-empty on every row.
    allowed : tuple of str
        Every column the manifest may have (others are refused: a typo would be ignored).
    paths : tuple of str
        Columns holding paths, resolved against the manifest's folder.

    Raises
    ------
    BatchError
        Missing file, no header, unknown or missing columns, an empty required cell, no rows.
    """
    p = Path(path)
    if p.is_dir():
        raise BatchError(f"manifest {p} is a folder, not a CSV file")
    if not p.is_file():
        raise BatchError(f"manifest {p} does not exist")
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            raw, lines = [], []
            for row in reader:               # each row's line in the file (for messages)
                raw.append(row)
                lines.append(reader.line_num)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise BatchError(f"manifest {p} is not a CSV file ({exc})") from None
    if not header:
        raise BatchError(f"manifest {p} is empty (expected a header row with {required[0]!r})")
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:                      # before: the last one's cells silently won
        raise BatchError(f"manifest {p} has the column(s) {twice} more than once")
    unknown = [h for h in header if h not in allowed]
    if unknown:
        raise BatchError(f"manifest {p} has unknown column(s) {unknown}; expected some of "
                         f"{list(allowed)}")
    missing = [c for c in required if c not in header]
    if missing:
        raise BatchError(f"manifest {p} lacks the column(s) {missing} (header: {header})")
    rows = []
    for line, row in zip(lines, raw):
        if any((c or "").strip() for c in row.get(None) or ()):  # more cells than the header
            # (before: dropped silently; empty ones, a spreadsheet's trailing commas, pass)
            raise BatchError(f"manifest {p} line {line} has {len(header) + len(row[None])} "
                             f"cells, its header {len(header)}")
        cells = {(k or "").strip(): (v or "").strip() for k, v in row.items() if k is not None}
        if not any(cells.values()):
            continue  # blank line
        for c in required:
            if not cells.get(c):
                raise BatchError(f"manifest {p} line {line}: column {c!r} is empty")
        rows.append({LINE: str(line), **{k: (_resolve(v, p.parent) if k in paths else v)
                                         for k, v in cells.items() if v}})
    if not rows:
        raise BatchError(f"manifest {p} has no rows")
    return rows


def _check_face(text: str | None, what: str) -> None:
    """A face cell or option that names a place (:func:`facetransfer.track.face_crop.
    face_place`; whether a point lies in the frame is checked when the clip is read)."""
    if text is None:
        return
    from ..errors import TrackError
    from ..track.face_crop import face_place

    try:
        face_place(text, what)
    except TrackError as exc:
        raise BatchError(str(exc)) from None


def _max_frames(value, what: str) -> int | None:
    """A frame limit (``--max-frames``, a ``max_frames`` cell): None, or a whole number >= 1."""
    if value is None:
        return None
    try:
        n = int(str(value).strip())
    except ValueError:
        raise BatchError(f"{what} must be a whole number of frames >= 1, got "
                         f"{str(value)!r}") from None
    if n < 1:
        raise BatchError(f"{what} must be >= 1, got {n}")
    return n


#: The words of an ``occluders`` cell (case aside): yes and no.
_YES, _NO = ("yes", "true", "1", "on"), ("no", "false", "0", "off")


def _occluders(text: str | None, default: bool, what: str) -> bool:
    """An ``occluders`` cell: yes or no (:data:`_YES`, :data:`_NO`); empty: ``default``."""
    if text is None:
        return default
    word = text.strip().lower()
    if word in _YES or word in _NO:
        return word in _YES
    raise BatchError(f"{what} must be yes or no (true/false, 1/0), got {text!r}")


def _name(explicit: str | None, path: str | os.PathLike, where: str) -> str:
    name = explicit or _stem(path)
    if not name or name in (".", "..") or "/" in name or "\\" in name or name.startswith("."):
        raise BatchError(f"{where}: {name!r} cannot be an output file name")
    return name


def _stem(path: str | os.PathLike) -> str:
    """A video's name for its outputs: its file name without the extension; of an image
    sequence, without the frame-number field too (``plate/kh.####.png``: ``kh``), else its
    folder's name (``shot12/%04d.png``: ``shot12``)."""
    from ..io.video_sequence import FRAME_FIELD, is_sequence

    p = Path(path)
    if not is_sequence(p):
        return p.stem
    return FRAME_FIELD.sub("", p.stem).strip("._- ") or p.resolve().parent.name


def clip_jobs(videos=(), manifest: str | os.PathLike | None = None, *,
              init: str = "auto", face: str | None = None,
              max_frames: int | None = None, occluders: bool = False) -> list[ClipJob]:
    """The clips of ``batch track``: videos given directly (with the initial points ``init``,
    the person ``face``, the frame limit ``max_frames`` and ``occluders``) and/or the rows of a
    manifest (with their ``init``, ``face``, ``max_frames`` and ``occluders`` columns; an empty
    ``face``, ``max_frames`` or ``occluders`` cell takes ``face``, ``max_frames`` or
    ``occluders``).

    Raises
    ------
    BatchError
        No clip at all, a bad manifest, a face that names no place, a frame limit that is not
        a whole number >= 1, an ``occluders`` cell neither yes nor no, or two clips with the
        same name.
    """
    _check_face(face, "--face")
    max_frames = _max_frames(max_frames, "--max-frames")
    jobs = [ClipJob(_name(None, v, f"video {v}"), absolute(v),
                    str(init) if init == "auto" else absolute(init), face, max_frames,
                    bool(occluders))
            for v in videos]
    if manifest is not None:
        for row in read_manifest(manifest, required=("video",), allowed=CLIP_COLUMNS,
                                 paths=("video", "init")):
            where = f"manifest {manifest} line {row[LINE]}"
            _check_face(row.get("face"), f"{where}: face")
            limit = _max_frames(row.get("max_frames"), f"{where}: max_frames")
            jobs.append(ClipJob(_name(row.get("name"), row["video"], where), row["video"],
                                row.get("init", "auto"), row.get("face", face),
                                max_frames if limit is None else limit,
                                _occluders(row.get("occluders"), bool(occluders),
                                           f"{where}: occluders")))
    if not jobs:
        raise BatchError("no clips: give VIDEO files or --manifest clips.csv")
    check_unique_names(jobs)
    return jobs


def pair_jobs(manifest: str | os.PathLike) -> list[PairJob]:
    """The transfers of ``batch transfer``: one per row of a pairs manifest.

    Raises
    ------
    BatchError
        A bad manifest, a row with nothing to transfer, a track column without its video, or
        two rows with the same name.
    """
    rows = read_manifest(manifest, required=("target",),
                         allowed=PAIR_PATH_COLUMNS + PAIR_VALUE_COLUMNS, paths=PAIR_PATH_COLUMNS)
    jobs = []
    for row in rows:
        where = f"manifest {manifest} line {row.pop(LINE)}"
        for track, video in (("source_track", "expression_from"), ("viseme_track", "viseme_from"),
                             ("identity_track", "identity_from"), ("pose_track", "pose_from")):
            if row.get(track) and not row.get(video):
                raise BatchError(f"{where}: {track} needs {video} (the video it belongs to)")
        if not any(row.get(c) for c in PAIR_SOURCES):
            raise BatchError(f"{where}: nothing to transfer (give one of {list(PAIR_SOURCES)})")
        _check_pair_tracks(row, where)
        for col in ("target_face", "source_face"):
            _check_face(row.get(col), f"{where}: {col}")
        if row.get("identity_from") and (row.get("identity_label") or row.get("identity_weights")):
            raise BatchError(f"{where}: give one of identity_from, identity_label, "
                             "identity_weights")
        sources = {k: v for k, v in row.items() if k not in ("target", "name")}
        jobs.append(PairJob(_name(row.get("name"), row["target"], where), Path(row["target"]),
                            sources))
    check_unique_names(jobs)
    return jobs


def _check_pair_tracks(row: dict, where: str) -> None:
    """BatchError where a track column of a pairs row holds a transfer's saved performance
    (``transfer --save-track``), not the clip's track
    (:func:`facetransfer.transfer_plan.performance_given`): refused with the manifest, before
    any job runs."""
    from ..transfer_plan import TRACK_FLAGS, performance_given

    for kind, flag in TRACK_FLAGS.items():   # the columns are the options' names
        col = flag[2:].replace("-", "_")
        video = "target" if kind == "target" else f"{kind}_from"
        line = performance_given(row[col], col, kind, row.get(video)) if row.get(col) else None
        if line:
            raise BatchError(f"{where}: {line}")


def export_jobs(tracks) -> list[ExportJob]:
    """The track files of ``batch export``, named by their stems."""
    jobs = [ExportJob(_name(None, t, f"track {t}"), Path(absolute(t))) for t in tracks]
    if not jobs:
        raise BatchError("no track files given")
    check_unique_names(jobs, hint="files of distinct names")
    return jobs


def check_unique_names(jobs, *, hint: str = "a manifest's 'name' column, or files of distinct "
                       "names") -> None:
    """Refuse two jobs whose outputs would have the same name (also differing only in case,
    which is one file on macOS and Windows).

    Raises
    ------
    BatchError
        Naming both inputs of the first clash.
    """
    seen: dict[str, object] = {}
    for job in jobs:
        key = job.name.casefold()
        if key in seen:
            a, b = seen[key].inputs[0], job.inputs[0]
            raise BatchError(f"two clips have the name {job.name!r} ({a} and {b}); give them "
                             f"distinct names ({hint})")
        seen[key] = job
