"""The Dask cluster a batch runs on: an embedded :class:`dask.distributed.LocalCluster` (one
single-threaded worker process per core) or the scheduler of a real cluster.

The workers must see the inputs and the output folder at the same paths as the client (a shared
file system); the model is scattered to them once (:func:`scatter_model`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from typing import Iterator

from .manifest import BatchError

log = logging.getLogger(__name__)

__all__ = ["open_client", "quiet_dask", "default_workers", "scatter_model", "DASK_LOGGERS"]

#: Loggers of Dask and its web stack, silenced unless ``-v``.
DASK_LOGGERS = ("distributed", "dask", "tornado", "bokeh", "asyncio")
#: Seconds a scheduler has to answer.
CONNECT_TIMEOUT = 10.0


def quiet_dask(verbose: bool = False) -> None:
    """Keep Dask's own log lines (worker start, "Compute Failed"...) out of the way unless
    ``verbose``: a failed task is reported as its clip's row."""
    level = logging.INFO if verbose else logging.CRITICAL
    # Dask's configuration gives some children levels of their own (``distributed.client``:
    # WARNING, which printed a lost scheduler's tracebacks without -v): every one set
    known = [n for n in logging.root.manager.loggerDict
             if any(n == p or n.startswith(p + ".") for p in DASK_LOGGERS)]
    for name in (*DASK_LOGGERS, *known):
        logging.getLogger(name).setLevel(level)


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def _probe(address: str, timeout: float) -> None:
    """Raise :class:`BatchError` unless something listens at a ``tcp://HOST:PORT`` address."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        proto, loc = parse_address(address)
        if proto != "tcp":
            return  # tls://, ucx://...: left to Dask
        host, port = parse_host_port(loc)
    except (ValueError, TypeError):
        raise BatchError(f"--scheduler {address!r} is not an address like "
                         "tcp://HOST:8786") from None
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as exc:
        raise BatchError(f"scheduler {address} does not answer ({exc.strerror or exc}); start "
                         "it with `dask scheduler` and check the address") from None


@contextlib.contextmanager
def open_client(*, workers: int | None = None, scheduler: str | None = None,
                timeout: float = CONNECT_TIMEOUT, processes: bool = True,
                verbose: bool = False) -> Iterator[object]:
    """A :class:`dask.distributed.Client` for the run; the embedded cluster is closed on exit.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core). Not with
        ``scheduler``.
    scheduler : str, optional
        Address of a running scheduler (``tcp://HOST:8786``) instead of an embedded cluster.
    timeout : float
        Seconds the scheduler has to answer.
    processes : bool
        Embedded workers as processes (the default) or threads of this process (tests).
    verbose : bool
        Let Dask log.

    Raises
    ------
    BatchError
        ``workers < 1``, ``workers`` with ``scheduler``, a scheduler that does not answer.
    """
    from dask.distributed import Client

    quiet_dask(verbose)
    if scheduler is not None:
        if workers is not None:
            raise BatchError("--workers sizes the embedded cluster; the workers of --scheduler "
                             "are the ones started with `dask worker`")
        client = _remote_client(scheduler, timeout)
        try:
            yield client
        finally:
            client.close()
        return
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise BatchError(f"--workers must be >= 1, got {workers}")
    cluster = _local_cluster(n, processes, verbose)
    try:
        client = Client(cluster, set_as_default=False)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def _remote_client(scheduler: str, timeout: float):
    """A client of the running scheduler at ``scheduler`` (BatchError if it does not answer)."""
    from dask.distributed import Client

    _probe(scheduler, timeout)
    try:
        return Client(scheduler, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise BatchError(f"scheduler {scheduler} did not answer within {timeout:g} s "
                         f"({exc})") from None
    except (TypeError, ValueError) as exc:  # tls:// without certificates, a bad address
        raise BatchError(f"cannot connect to scheduler {scheduler}: {exc}") from None


def _local_cluster(n: int, processes: bool, verbose: bool):
    """An embedded cluster of ``n`` single-threaded workers (processes or threads)."""
    from dask import config
    from dask.distributed import LocalCluster

    level = logging.INFO if verbose else logging.CRITICAL  # a failed task is its clip's row
    kw = {}
    if processes:
        # OpenCV's parallel_for_ on one thread, as Dask's nanny sets OpenBLAS's (a worker per
        # core: a pool's threads would only spin beside the others, cli.main.SERIAL_POOLS);
        # without -v, no native log lines of MediaPipe and FFmpeg in the workers
        quiet = () if verbose else (("GLOG_minloglevel", "2"), ("OPENCV_FFMPEG_LOGLEVEL", "-8"),
                                    ("OPENCV_LOG_LEVEL", "SILENT"))
        kw["env"] = {k: os.environ.get(k, v)
                     for k, v in (("OPENCV_FOR_THREADS_NUM", "1"), *quiet)}
    # workers that may start processes of their own (the renderer forks for long clips);
    # started with Ctrl-C ignored, which they inherit: a terminal's Ctrl-C reaches every
    # process of the group, and only this one (the client) is to act on it (cancel, summary,
    # one line), not each worker with a traceback
    with config.set({"distributed.worker.daemon": False}), _ctrl_c_ignored(processes):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                            dashboard_address=None, silence_logs=level, **kw)


@contextlib.contextmanager
def _ctrl_c_ignored(active: bool):
    """SIGINT ignored while the block runs (in the main thread, where signals can be set),
    then the handler before it again."""
    import signal
    import threading

    if not active or threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def scatter_model(client, model):
    """Send the model to every worker once; pass the returned future to the tasks.

    Returns
    -------
    distributed.Future
        Resolved to the model on each worker (not pickled with each task).
    """
    if model is None:
        return None
    return client.scatter(model, broadcast=True, hash=False)
