"""The model of a batch run as its tasks receive it: the model file's path and content hash
(:class:`ModelRef`), each worker process loading it once (:func:`worker_model`).

Before the fifty-third session the model was scattered to every worker (``client.scatter(model,
broadcast=True)``). On a user's own scheduler Dask's active memory manager (on by default: its
ReduceReplicas policy) dropped the copies no task waited for, leaving one; when that worker was
lost (killed, out of memory, taken for lost) the scheduler said "the cluster lost scattered
data" and cancelled every clip left, none run again (the embedded cluster ran with the manager
off for that reason). A :class:`ModelRef` is a few bytes in each task: there is no data on the
cluster to lose, and a worker started again (a nanny's restart, a worker joining) loads the
model from the file as the others did. A model file is mapped, not read (its core, hundreds of
MB, :func:`facetransfer.model.load_model`): the workers of one machine share its pages, where
each held a copy of its own of the scattered model.

A model without a file that still holds it (built in memory by a library caller; a file
touched since, its content the same, still holds it), or whose file some of the workers do not see (:func:`hosts_without`: machines without
the shared file system, nor the default model in their own cache), is scattered as before
(:func:`facetransfer.batch.cluster.scatter_model`).
"""

from __future__ import annotations

import collections
import logging
import socket
import threading
from dataclasses import dataclass
from pathlib import Path

from .manifest import BatchError

log = logging.getLogger(__name__)

__all__ = ["ModelRef", "model_ref", "worker_model", "hosts_without", "release"]

#: Models a worker process keeps loaded (the last ones used): a worker serving two runs of
#: different models at once loads each once. Each is dropped as its run ends (:func:`release`).
KEPT = 2

_LOADED: "collections.OrderedDict[str, object]" = collections.OrderedDict()
_LOCK = threading.Lock()


@dataclass(frozen=True)
class ModelRef:
    """A model file as the client found it: its absolute ``path`` and the model's
    ``content_hash`` (sha256 hex), which the file a worker loads must have; ``default``: it is
    the default model, which a worker that does not see ``path`` (the client's user cache) may
    take from its own cache where that holds the same model."""

    path: str
    content_hash: str
    default: bool = False


def model_ref(model) -> ModelRef | None:
    """The :class:`ModelRef` of ``model``, None where it has no file that still holds it
    (:func:`facetransfer.model.model_file`; a file touched since it was loaded, its content
    the same, still holds it: :func:`facetransfer.model.file_written_over` judges it by its
    content)."""
    from ..default_model import default_model_path
    from ..model import file_written_over, model_file

    # a file only touched since (another modification time, the same content) is confirmed
    # by its content and taken as it is now: before, it was taken for another file and the
    # whole model was sent to every worker instead of its path (batch55)
    file_written_over(model)
    path = model_file(model)
    if path is None:
        return None
    default = path == default_model_path().absolute()
    return ModelRef(str(path), model.content_hash, default)


def hosts_without(client, ref: ModelRef) -> list[str]:
    """The hosts of the client's workers (those there now) that have no file of the model of
    ``ref``: neither at its path nor, for the default model, in their own cache, with the
    run's hash in its metadata (:func:`facetransfer.default_model.stated_hash`); asked of each (``client.run``); a worker
    that fails to answer (ending) is left out."""
    seen = client.run(_sees, ref, on_error="ignore")
    return sorted({host for ok, host in seen.values() if not ok})


def release(client, ref: ModelRef) -> None:
    """At a run's end, the client's workers drop the model of ``ref`` from those they keep
    (:func:`worker_model`): a user's long-lived cluster holds nothing of a run that is over
    (before, each worker kept it until two other models were used: the core's pages it had
    read stayed mapped, counted in its memory as Dask measures it, 126 MB of a worker idle
    after a 30-frame track, review53b). A run of the same model still going on them loads it
    again once (mapped, its sha256 not read again: 0.07 s). A worker that fails to answer is
    left out; a client that cannot ask is logged."""
    try:
        client.run(_release, ref.content_hash, on_error="ignore")
    except Exception as exc:  # noqa: BLE001 - the run is over; its summary is still written
        log.debug("the workers were not asked to drop the model %s: %s", ref.path, exc)


def _release(content_hash: str) -> None:
    """Run on a worker: the model of ``content_hash`` no longer kept."""
    with _LOCK:
        _LOADED.pop(content_hash, None)


def _sees(ref: ModelRef) -> tuple[bool, str]:
    """Run on a worker: whether a file it would load (:func:`_paths`) says it holds the run's
    model (its metadata's hash; the load checks the content), and the host's name. A machine's
    own default model of another build than the client's (another version's, or the same
    recipe's bits on another machine) was taken as seen: the model was not sent, and each of
    that worker's clips failed, "holds another model now ... replaced since the run began?"
    (review53b)."""
    from ..default_model import stated_hash

    return any(stated_hash(p) == ref.content_hash for p in _paths(ref)), \
        socket.gethostname()


def _paths(ref: ModelRef) -> list[Path]:
    """The files a worker loads the model of ``ref`` from: its path, or for the default model
    where this machine does not see that path, this machine's default model file, and a file
    of the run's model it keeps of another version's code (the rename of the default model by
    its recipe, cache54, left a machine's earlier build of the same bits under another name)."""
    from ..default_model import default_model_path, kept_model

    paths = [Path(ref.path)]
    if ref.default and not paths[0].is_file():
        paths.append(default_model_path())
        kept = kept_model(ref.content_hash)   # this machine's build of another version's code
        paths += [kept] if kept is not None else []
    return paths


def worker_model(model):
    """``model`` where it is a model (or None); the model of a :class:`ModelRef`, loaded once
    by this process (the last :data:`KEPT` kept, by content hash), and again where its file
    was written over in place since (:func:`facetransfer.model.file_written_over`: a ``cp``
    onto it; its core is mapped, and a worker's later tasks, this run's or a later one's,
    read the new bytes under the old hash, silently another model).

    Raises
    ------
    BatchError
        The file cannot be loaded here or holds another model (replaced since the run began):
        naming the path and this host.
    """
    if not isinstance(model, ModelRef):
        return model
    from ..model import file_written_over

    with _LOCK:
        found = _LOADED.get(model.content_hash)
        if found is not None and file_written_over(found):
            found = None              # its mapped core reads the new bytes: loaded and checked
        if found is None:
            found = _load(model)
            _LOADED[model.content_hash] = found
            while len(_LOADED) > KEPT:
                _LOADED.popitem(last=False)
        _LOADED.move_to_end(model.content_hash)
        return found


def _load(ref: ModelRef):
    """The model of ``ref`` read from its path (or, for the default model where this machine
    does not see that path, from this machine's default model file); BatchError if not."""
    paths = _paths(ref)
    why = ""
    for p in paths:
        model, why = _try_load(p, ref.content_hash, own=p != Path(ref.path))
        if model is not None:
            return model
    unseen = not any(p.is_file() for p in paths)
    raise BatchError(f"the run's model {ref.path} cannot be loaded on the worker on "
                     f"{socket.gethostname()}: {why}" + (
                         " (every worker must see the model file at the client's path, e.g. "
                         "on a shared file system: give --model /shared/M.npz)" if unseen
                         else ""))


def _try_load(path: Path, content_hash: str, *, own: bool = False):
    """``(model, "")`` of the model file ``path`` where it holds the model of ``content_hash``,
    else ``(None, why)`` (``own``: ``path`` is this machine's own default model)."""
    from ..errors import ModelFileError
    from ..model import load_model

    if not path.is_file():
        return None, f"{path} is not there"
    try:
        model = load_model(path)
    except (ModelFileError, OSError) as exc:
        return None, str(exc)
    if model.content_hash != content_hash:
        return None, (f"{path} holds another model now (sha256 {model.content_hash[:12]}, the "
                      f"run's {content_hash[:12]}): " + (
                          "this machine's own default model, another build than the client's"
                          if own else "replaced since the run began?"))
    return model, ""
