"""The tasks of a batch track run (:func:`.run.batch_track`): each clip in one task, or its
frames counted, its chunks tracked in parallel and joined, the chunks of at most
:attr:`TrackSubmit.MAX_CLAIMS` clips claimed at once.

Moved out of :mod:`.run` (which collects the rows, skips what is done and writes the summary
for every kind of run) in the fifty-second session, unchanged: that module had grown to 833 of
the 900 lines a module may have.

``TrackSubmit(client, col, outs, mf, options, chunk, overlap, keys, planned, owners)``:
``col`` the run's collector (:class:`.run._Collector`: its ``add``, ``fail``, ``finish`` and
``alive``), ``outs`` ``{name: output path}``, ``mf`` the model scattered to the workers,
``options`` the tracker's settings, ``keys`` ``{name: job digest}``, ``planned`` ``{name:
the output's identity}`` (:func:`.run._planned`), ``owners`` ``{name: claim owner}``
(:func:`.run._owners`).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses

from . import jobs as J
from . import ownership as O
from .chunks import plan_chunks

__all__ = ["TrackSubmit"]


class TrackSubmit:
    """The tasks of :func:`.run.batch_track`: a clip in one task, or (``chunk``) its frames counted
    first, then its chunks tracked in parallel (the first one first) and joined. The chunks
    of a clip are claimed by this process, the client (:func:`.ownership.claimed`,
    ``DIR/.NAME.npz.chunks.claim``), from before its count to its join's end: another run's
    chunks of it fail at once, "its chunks are being tracked by another run" (before, two runs
    of one batch at once both tracked every chunk, and one join's write failed). A chunk's
    track goes to the join as a Dask result, no file: there is no chunk of another run to
    take, nor one to be replaced under a join. At most :attr:`MAX_CLAIMS` clips are claimed
    (and under way) at once, the others queued."""

    #: Clips whose chunks the client claims at once, each claim an open file; no more than a
    #: quarter of the files the process may open (:func:`_claims_at_once`). Before, every
    #: clip's was taken as the run began: a run of more clips than the process may open files
    #: (1024 by default on Linux) ran the rest unclaimed, without a word, its descriptors
    #: spent (300 clips under a limit of 200: 136 unclaimed). Enough clips under way to keep
    #: a cluster of a few hundred workers busy: each has a count and two chunks or more.
    MAX_CLAIMS = 256

    def __init__(self, client, col, outs: dict, mf, options, chunk: int, overlap: int,
                 keys: dict, planned: dict, owners: dict) -> None:
        self.client, self.col, self.outs, self.mf = client, col, outs, mf
        self.options, self.chunk, self.overlap, self.keys = options, chunk, overlap, keys
        self.planned = planned   # what a job may replace (run._planned): not another run's
        self.owners = owners     # each job's claim's owner (run._owners)
        self.held = contextlib.ExitStack()     # the chunk claims, released at the run's end
        self.claims: dict[str, contextlib.ExitStack] = {}
        self.queued: collections.deque = collections.deque()   # clips waiting for a claim

    def submit(self, job) -> None:
        if self.chunk:   # a clip of more than max_frames: the chunks of its first max_frames
            self.queued.append(job)
            self._next()
        else:
            self._whole(job)

    def _next(self) -> None:
        """Claim the chunks of the clips queued while fewer than :attr:`MAX_CLAIMS` are held,
        and count their frames. While a clip is queued, as many are under way (each claimed
        clip has a task until its row is final, which releases its claim and calls this): the
        run's collector never runs out of tasks with clips left."""
        while self.queued and len(self.claims) < _claims_at_once(self.MAX_CLAIMS):
            job = self.queued.popleft()
            claim = contextlib.ExitStack()
            try:
                claim.enter_context(O.claimed(self.outs[job.name], self.owners[job.name],
                                              part="chunks"))
            except O.OutputTaken as exc:
                self.col.fail(job, exc, self.outs[job.name])
                continue
            self.claims[job.name] = self.held.enter_context(claim)
            self.col.add(self.client.submit(J.count_frames, str(job.video), job.max_frames,
                                            pure=False), "count", job)

    def _whole(self, job) -> None:
        self.col.add(self.client.submit(J.track_clip, job, str(self.outs[job.name]), self.mf,
                                        self.options, planned=self.planned[job.name],
                                        owner=self.owners[job.name], pure=False), "clip", job)

    def _chunks(self, job, n_frames: int) -> None:
        out, mf, opt = str(self.outs[job.name]), self.mf, self.options
        chunks = plan_chunks(n_frames, self.chunk, self.overlap)
        if len(chunks) == 1:
            self._whole(job)
            return
        submit = self.client.submit
        first = submit(J.track_chunk, job, chunks[0], out, mf, opt, pure=False, priority=1)
        rest = [submit(J.track_chunk, job, c, out, mf, opt, first, pure=False)
                for c in chunks[1:]]
        self.col.alive += [first] + rest
        self.col.add(submit(J.join_clip, job, out, mf, chunks, [first] + rest,
                            planned=self.planned[job.name], owner=self.owners[job.name],
                            pure=False), "clip", job)

    def on_done(self, kind: str, job, fut) -> None:
        try:
            res = fut.result()
        except Exception as exc:  # noqa: BLE001 (any failure is this clip's row)
            self._release(job)
            self.col.fail(job, exc, self.outs[job.name])
            return
        if kind == "count":
            self._chunks(job, int(res))
        else:
            self._release(job)
            self.col.finish(job, dataclasses.replace(res, job=self.keys[job.name]))

    def _release(self, job) -> None:
        """Let go of the claim of the chunks of ``job``'s clip (its row is final), and claim
        the next clip queued."""
        claim = self.claims.pop(job.name, None)
        if claim is not None:
            claim.close()
            self._next()


def _claims_at_once(most: int) -> int:
    """``most``, or a quarter of the files this process may open where that is fewer (the
    rest for Dask's connections, the summary, the videos of a threads cluster)."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (ImportError, OSError, ValueError):   # not POSIX
        return most
    return most if soft == resource.RLIM_INFINITY else max(1, min(most, soft // 4))
