"""Resuming an interrupted tracking run.

:func:`facetransfer.track.track_video` with a ``checkpoint`` path saves what it has finished (the
initialisation of §5.2, the solved frames of the current pass of §5.1, the previous pass and the
identity systems accumulated so far) every few seconds and when it is interrupted. A later call
with the same video, model, options and initial points continues from there; anything else
(another video, model or option) starts afresh. The file is written atomically and removed once
the track is complete.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from ..errors import OutputError
from ..io.atomic import atomic_path
from .camera import Pose
from .solver import FrameState

log = logging.getLogger(__name__)

#: bumped when the saved layout changes (older checkpoints are then ignored)
CHECKPOINT_VERSION = 1


def checkpoint_key(video_id: str, n_frames: int, model_hash: str, options, init, fixed) -> str:
    """sha256 of everything a saved run depends on.

    Parameters
    ----------
    video_id : str
        Identifies the frames (:func:`video_identity`).
    n_frames : int
    model_hash : str
    options : TrackOptions
    init : "auto", (68, 2) array or None
        Initial points (``"auto"``: detected; the detection is stored in the checkpoint).
    fixed : dict mode -> (r,) array
    """
    ini = init if isinstance(init, str) else np.asarray(init, np.float64).round(6).tolist()
    doc = {"video": video_id, "frames": int(n_frames), "model": model_hash,
           "options": dataclasses.asdict(options), "init": ini,
           "fixed": {k: np.asarray(v, np.float64).round(12).tolist()
                     for k, v in sorted((fixed or {}).items())},
           "version": CHECKPOINT_VERSION}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def video_identity(path: str | None, first: np.ndarray | None = None,
                   last: np.ndarray | None = None) -> str:
    """A video file by its resolved path, size and modification time; an image sequence by its
    files' (:func:`facetransfer.io.video_sequence.sequence_stamp`); an in-memory clip by the
    checksum of its first and last frames."""
    from ..io.video_sequence import is_sequence, sequence_stamp

    if path and is_sequence(path):
        return "sequence:" + sequence_stamp(path)
    if path:
        st = os.stat(path)
        return f"{Path(path).resolve()}:{st.st_size}:{st.st_mtime_ns}"
    h = hashlib.sha256()
    for f in (first, last):
        if f is not None:
            a = np.ascontiguousarray(f)
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    return "array:" + h.hexdigest()


def _pack_states(states: list, modes) -> dict:
    """Frame states (some None) -> arrays with a ``valid`` mask."""
    n = len(states)
    valid = np.array([s is not None for s in states], bool)
    ref = next((s for s in states if s is not None), None)
    out = {"valid": valid,
           "R": np.zeros((n, 3, 3)), "s": np.zeros(n), "t": np.zeros((n, 2))}
    for m in modes:
        r = 0 if ref is None else np.asarray(ref.weights[m]).size
        out[f"w_{m}"] = np.zeros((n, r))
    for i, st in enumerate(states):
        if st is None:
            continue
        out["R"][i], out["s"][i], out["t"][i] = st.pose.rotation, st.pose.scale, st.pose.translation
        for m in modes:
            out[f"w_{m}"][i] = st.weights[m]
    return out


def _unpack_states(d: dict, prefix: str, modes) -> list:
    valid = d[prefix + "valid"]
    out = []
    for i in range(valid.size):
        if not valid[i]:
            out.append(None)
            continue
        out.append(FrameState(Pose(d[prefix + "R"][i].copy(), float(d[prefix + "s"][i]),
                                   d[prefix + "t"][i].copy()),
                              {m: d[prefix + f"w_{m}"][i].copy() for m in modes}))
    return out


@dataclasses.dataclass
class Resume:
    """What a checkpoint restores (see :class:`Checkpoint`)."""

    start: int
    L0: np.ndarray
    state0: FrameState
    pass_index: int
    next_frame: int
    states: list
    prev: list | None
    conf: np.ndarray
    lost: np.ndarray
    reinit: list
    systems: list


class ProgressFile:
    """An atomic ``.npz`` progress file of a long run, keyed by what the run depends on.

    Parameters
    ----------
    path : path-like
    key : str
        Identifies the run (a file with another key is another run's).
    every : float
        Seconds between periodic saves (0 = after every frame).
    best_effort : bool
        A save that cannot be written (a full disk, an unwritable folder) is a warning and no
        more saves follow, instead of an error: a cache's progress file, which must never fail
        the job it belongs to (:mod:`facetransfer.track.cache`).
    """

    def __init__(self, path, key: str, *, every: float = 20.0, best_effort: bool = False) -> None:
        self.path = Path(path)
        self.key = key
        self.every = float(every)
        self.best_effort = bool(best_effort)
        self._last = time.monotonic()
        self._wait = self.every
        self._broken = False
        self.saves = 0

    def due(self) -> bool:
        """Whether a periodic save is due (never after a best-effort save failed)."""
        return not self._broken and time.monotonic() - self._last >= self._wait

    def _entries(self, unreadable: str) -> dict | None:
        """The file's arrays by name; None when there is no file, or when it is not a readable
        ``.npz`` (empty, truncated, another format): then ``unreadable`` is logged, a
        ``%s (%s)`` message filled with the path and the error's type."""
        if not self.path.is_file():
            return None
        try:
            with np.load(self.path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except Exception as exc:  # zipfile.BadZipFile, EOFError, ValueError, OSError…
            log.warning(unreadable, self.path, exc.__class__.__name__)
            return None

    def _write(self, arrays: dict) -> None:
        """Write ``arrays`` to the file atomically (the folder is created if needed)."""
        if self._broken:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(self.path) as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, **arrays)
        except (OSError, OutputError) as exc:
            if not self.best_effort:
                raise
            self._broken = True
            log.warning("could not save the progress to %s (%s); going on without it",
                        self.path, exc)
            return
        self._last = time.monotonic()
        self.saves += 1

    def remove(self) -> None:
        """Delete the file (the run is complete, or the file unreadable). Nothing there (its
        folder a file, too) is nothing to delete; a best-effort file that cannot be deleted
        is a warning (a cache's must never fail the job, e.g. a track cache whose folder is a
        file must not fail ``transfer`` with "Not a directory")."""
        try:
            self.path.unlink()
        except (FileNotFoundError, NotADirectoryError):
            pass
        except OSError as exc:
            if not self.best_effort:
                raise
            self._broken = True
            log.warning("could not remove the progress file %s (%s); going on without it",
                        self.path, exc)


class Checkpoint(ProgressFile):
    """A tracking run's progress file (atomic ``.npz``).

    Parameters
    ----------
    path : path-like
    key : str
        :func:`checkpoint_key` of the run.
    modes : sequence of str
        The model's mode names.
    every : float
        Seconds between periodic saves (0 = after every frame).
    """

    def __init__(self, path, key: str, modes, *, every: float = 20.0) -> None:
        super().__init__(path, key, every=every)
        self.modes = tuple(modes)

    def load(self) -> Resume | None:
        """The saved progress, or None (no file, another run's, unreadable)."""
        d = self._entries("ignoring unreadable checkpoint %s (%s); starting afresh")
        if d is None:
            return None
        if str(d.get("key", "")) != self.key:
            log.warning("checkpoint %s belongs to another run (video, model or options "
                        "differ); starting afresh", self.path)
            return None
        try:
            return self._resume(d)
        except Exception as exc:  # keys missing, wrong shapes or dtypes: a damaged file
            log.warning("ignoring damaged checkpoint %s (%s); starting afresh", self.path,
                        exc.__class__.__name__)
            return None

    def _resume(self, d: dict) -> Resume:
        st0 = _unpack_states(d, "s0_", self.modes)[0]
        prev = _unpack_states(d, "prev_", self.modes) if bool(d["has_prev"]) else None
        n_sys = int(d["n_systems"])
        systems = [(d["sys_S"][k], d["sys_c"][k]) for k in range(n_sys)]
        r = Resume(int(d["start"]), np.asarray(d["L0"], np.float64), st0, int(d["pass_index"]),
                   int(d["next_frame"]), _unpack_states(d, "cur_", self.modes), prev,
                   d["conf"].astype(np.float64), d["lost"].astype(bool),
                   [int(i) for i in d["reinit"]], systems)
        n = len(r.states)
        if (r.L0.shape != (68, 2) or r.conf.shape != (n,) or r.lost.shape != (n,)
                or not 0 <= r.start <= r.next_frame <= n or r.pass_index < 0
                or (prev is not None and len(prev) != n)):
            raise ValueError("inconsistent arrays")
        return r

    def save(self, *, start: int, L0, state0: FrameState, pass_index: int, next_frame: int,
             states: list, prev: list | None, conf, lost, reinit, systems) -> None:
        """Write the progress atomically (frames ``start .. next_frame - 1`` of the pass
        ``pass_index`` are solved)."""
        arrays = {"key": np.array(self.key), "version": np.array(CHECKPOINT_VERSION),
                  "start": np.array(start), "L0": np.asarray(L0, np.float64),
                  "pass_index": np.array(pass_index), "next_frame": np.array(next_frame),
                  "conf": np.asarray(conf, np.float64), "lost": np.asarray(lost, bool),
                  "reinit": np.asarray(reinit, np.int64).reshape(-1),
                  "has_prev": np.array(prev is not None), "n_systems": np.array(len(systems))}
        cur = [s if start <= i < next_frame else None for i, s in enumerate(states)]
        for prefix, sts in (("s0_", [state0]), ("cur_", cur), ("prev_", prev or [state0])):
            for k, v in _pack_states(sts, self.modes).items():
                arrays[prefix + k] = v
        if systems:
            arrays["sys_S"] = np.stack([np.asarray(S, np.float64) for S, _ in systems])
            arrays["sys_c"] = np.stack([np.asarray(c, np.float64) for _, c in systems])
        else:
            arrays["sys_S"] = np.zeros((0, 0, 0))
            arrays["sys_c"] = np.zeros((0, 0))
        self._write(arrays)
