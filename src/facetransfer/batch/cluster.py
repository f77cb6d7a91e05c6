"""The Dask cluster a batch runs on: an embedded :class:`dask.distributed.LocalCluster` (one
single-threaded worker process per core) or the scheduler of a real cluster.

The workers must see the inputs and the output folder at the same paths as the client (a shared
file system); each loads the model from its file once (:mod:`.model_ref`; a model built in
memory is scattered to them once, :func:`scatter_model`). A scheduler's address
(``tcp://`` or ``tls://``) is asked, within the timeout, whether a Dask scheduler answers there
before a client connects (:func:`_probe`: its host looked up on a thread, Dask's client waits
for the handshake of whatever listens, and for a name server, without a deadline); ``tls://``
takes the client's certificates from Dask's configuration, and is refused at once without them.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import time
from typing import Iterator

from .manifest import BatchError

log = logging.getLogger(__name__)

__all__ = ["open_client", "quiet_dask", "default_workers", "check_timeout", "scatter_model",
           "DASK_LOGGERS"]

#: Loggers of Dask and its web stack, silenced unless ``-v``.
DASK_LOGGERS = ("distributed", "dask", "tornado", "bokeh", "asyncio")
#: Seconds a scheduler has to answer.
CONNECT_TIMEOUT = 10.0
#: The longest wait for a scheduler taken (a day; 1e12 s overflowed a socket's deadline into a
#: traceback).
MAX_TIMEOUT = 86400.0


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


def check_timeout(timeout: float) -> float:
    """``timeout`` (seconds a scheduler has to answer) if in ``(0, MAX_TIMEOUT]``, else
    BatchError."""
    if not 0 < timeout <= MAX_TIMEOUT:        # also nan
        raise BatchError(f"--timeout must be a number of seconds > 0 and at most "
                         f"{MAX_TIMEOUT:g}, got {timeout:g}")
    return timeout


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (macOS, Windows)
        return max(1, os.cpu_count() or 1)


#: The end of the messages of an address where no scheduler answers.
SCHEDULER_HINT = "is it the scheduler's address? `dask scheduler` prints it, port 8786 by default"


def _probe(address: str, timeout: float) -> str:
    """The address to connect to (its host resolved) where a Dask scheduler answers at a
    ``tcp://`` or ``tls://`` ``HOST:PORT`` within ``timeout`` seconds, else
    :class:`BatchError`; another protocol's address is left to Dask.

    Each step is bounded by the one deadline: the host's lookup (on a thread: a DNS server
    that does not answer held the run for as long as the system's resolver waits), a plain
    connection (nothing listening, an unknown host: said at once), then Dask's own handshake
    (with TLS, its TLS handshake too) and an ``identity`` request: the client's connection
    reads the handshake without a deadline, so a port where something else listens (a web
    server, a program that accepts and says nothing) hung the run past ``--timeout``. The
    address returned names the host by the IP address that answered, so that the client does
    not look it up again without a deadline.
    """
    from distributed.comm.addressing import unparse_host_port

    where = _where(address)
    if where is None:
        return address  # ucx://, inproc://...: left to Dask
    proto, host, port = where
    deadline = time.monotonic() + timeout
    args = _tls_args(address) if proto == "tls" else {}      # said before any wait
    ips = _resolve(address, host, port, timeout)
    ip = _connect(address, ips, port, timeout, deadline)
    target = f"{proto}://{unparse_host_port(ip, port)}"
    kind = _dask_identity(target, address, timeout, max(deadline - time.monotonic(), 0.1), args)
    if kind in ("Worker", "Nanny"):
        raise BatchError(f"{address} is a Dask {kind.lower()}, not a scheduler; give the "
                         "scheduler's address (`dask scheduler` prints it, port 8786 by "
                         "default)")
    return target


def _where(address: str) -> tuple[str, str, int] | None:
    """``(protocol, host, port)`` of a ``tcp://`` or ``tls://`` address, None for another
    protocol; BatchError where it is not an address."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        proto, loc = parse_address(address)
        if proto not in ("tcp", "tls"):
            return None
        host, port = parse_host_port(loc)
    except (ValueError, TypeError):
        proto, host, port = "", "", -1
    if not 0 < port < 65536:     # before, port 99999 was "Connection refused"
        raise BatchError(f"--scheduler {address!r} is not an address like tcp://HOST:8786")
    return proto, host, port


def _tls_args(address: str) -> dict:
    """The client's TLS connection arguments of Dask's configuration
    (``distributed.comm.tls.*``, as :class:`distributed.Client` takes them); BatchError,
    before anything waits, where it names no certificates or ones that cannot be read."""
    import ssl

    from distributed.security import Security

    try:
        args = Security().get_connection_args("client")
    except (OSError, ValueError, ssl.SSLError) as exc:
        raise BatchError(f"--scheduler {address}: the TLS certificates of Dask's "
                         f"configuration cannot be used ({exc})") from None
    if args.get("ssl_context") is None:
        raise BatchError(f"--scheduler {address}: tls:// needs this client's certificates in "
                         "Dask's configuration (distributed.comm.tls.ca-file, .client.cert and "
                         ".client.key, e.g. DASK_DISTRIBUTED__COMM__TLS__CA_FILE=...), and "
                         "none are set; give them, or the scheduler's tcp:// address")
    return args


def _resolve(address: str, host: str, port: int, timeout: float) -> list[str]:
    """The IP addresses of ``host``, looked up on a daemon thread within ``timeout`` (a lookup
    that hangs is left behind: it cannot be stopped, nor hold the process at its exit)."""
    import threading

    found: dict = {}

    def look() -> None:
        try:
            found["infos"] = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except OSError as exc:
            found["error"] = exc

    th = threading.Thread(target=look, name="facetransfer-resolve", daemon=True)
    th.start()
    th.join(timeout)
    said = f"no Dask scheduler answered at {address}"
    if th.is_alive():
        raise BatchError(f"{said}: the host {host!r} was not found within {timeout:g} s (a name "
                         "server that does not answer?); check the address, or give the "
                         "scheduler's IP address")
    exc = found.get("error")
    if exc is not None:
        raise BatchError(f"{said}: the host {host!r} is not known ({exc.strerror or exc}); "
                         "check the address") from None
    return list(dict.fromkeys(info[4][0] for info in found["infos"]))


def _connect(address: str, ips: list[str], port: int, timeout: float, deadline: float) -> str:
    """The first of ``ips`` that accepts a connection at ``port`` before ``deadline``;
    BatchError naming ``address`` where none does."""
    said = f"no Dask scheduler answered at {address}"
    err: OSError = TimeoutError()
    for ip in ips:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            with socket.create_connection((ip, port), timeout=left):
                return ip
        except OSError as exc:
            err = exc
    if isinstance(err, TimeoutError):
        raise BatchError(f"{said} within {timeout:g} s: the connection was not accepted (a "
                         "machine that is down, a firewall?); check the address")
    raise BatchError(f"{said}: {err.strerror or err} (start it with `dask scheduler`, or check "
                     "the address)")


def _dask_identity(target: str, address: str, timeout: float, left: float,
                   args: dict) -> str:
    """The type (``"Scheduler"``, ``"Worker"``...) the Dask server at ``target`` (``address``
    resolved) says it is, asked within the ``left`` seconds of ``timeout`` (``args``: the TLS
    connection's); BatchError naming ``address`` where nothing answers in Dask's protocol."""
    import asyncio
    import ssl

    from distributed.comm import CommClosedError, connect

    async def ask():
        # deserialize=False: whatever answers is not trusted with unpickling
        comm = await connect(target, timeout=left, deserialize=False, **args)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    said = f"no Dask scheduler answered at {address}"
    try:
        reply = _run_coroutine(asyncio.wait_for(ask(), left))
    except TimeoutError:
        raise BatchError(f"{said} within {timeout:g} s: something there accepts connections "
                         f"but said nothing in Dask's protocol ({SCHEDULER_HINT})") from None
    except CommClosedError:
        raise BatchError(f"{said}: something there accepts connections but closed them "
                         f"without a Dask answer ({SCHEDULER_HINT})") from None
    except ssl.SSLError as exc:   # a refusal, not a wait: a plain-TCP server, a bad certificate
        raise BatchError(f"{said}: the TLS handshake failed ({exc.reason or exc}; a tls:// "
                         "address must be a scheduler started with TLS, whose certificate "
                         "Dask's configured CA verifies)") from None
    except OSError as exc:
        raise BatchError(f"{said} within {timeout:g} s ({exc.strerror or exc})") from None
    except Exception:  # noqa: BLE001 (bytes that are not Dask's frames: any decoding error)
        raise BatchError(f"{said}: something there answered, but not in Dask's protocol "
                         f"({SCHEDULER_HINT})") from None
    if not isinstance(reply, dict) or not isinstance(reply.get("type"), str):
        raise BatchError(f"{said}: the server there answered in Dask's protocol but not as a "
                         f"scheduler ({SCHEDULER_HINT})")
    return reply["type"]


def _run_coroutine(coro):
    """Run ``coro`` to its end on an event loop of its own (on a thread of its own where this
    one already runs a loop, e.g. in a notebook); the loop is closed after it."""
    import asyncio
    import concurrent.futures

    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return asyncio.run(coro)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coro).result()


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
        Address of a running scheduler (``tcp://HOST:8786``; ``tls://HOST:8786`` with the
        certificates of Dask's configuration) instead of an embedded cluster.
    timeout : float
        Seconds the scheduler has to answer (its host's lookup included).
    processes : bool
        Embedded workers as processes (the default) or threads of this process (tests).
    verbose : bool
        Let Dask log.

    Raises
    ------
    BatchError
        ``workers < 1``, ``workers`` with ``scheduler``, a timeout not in (0, MAX_TIMEOUT], a
        scheduler that does not answer.
    """
    from dask.distributed import Client

    quiet_dask(verbose)
    if scheduler is not None:
        if workers is not None:
            raise BatchError("--workers sizes the embedded cluster; the workers of --scheduler "
                             "are the ones started with `dask worker`")
        check_timeout(timeout)
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

    target = _probe(scheduler, timeout)
    try:
        return Client(target, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise BatchError(f"no Dask scheduler answered at {scheduler} within {timeout:g} s "
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
    # started with Ctrl-C held back (_start_signals_held), which they keep: a terminal's Ctrl-C
    # reaches every process of the group, and only this one (the client) is to act on it
    # (cancel, summary, one line), not each worker with a traceback. A Ctrl-C or SIGTERM to
    # this process meanwhile is raised once the cluster is whole, and the cluster closed:
    # raised in its start, the half-started cluster's close at the exit and its workers' start
    # printed tracebacks.
    # A model built in memory is scattered to every worker (scatter_model; a model of a file,
    # the CLI's, is loaded by each worker from it: .model_ref); Dask's active memory manager
    # drops the copies no task waits for, every 2 s, leaving one: a worker lost (its heartbeat
    # missed, or killed) then lost the model, and every clip not finished was cancelled ("its
    # worker died, more than once"), none run again. Off: each worker keeps its copy.
    cluster = None
    try:
        with config.set({"distributed.worker.daemon": False,
                         "distributed.scheduler.active-memory-manager.start": False}), \
                _start_signals_held(processes):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                                   dashboard_address=None, silence_logs=level, **kw)
    except BaseException:
        if cluster is not None:
            cluster.close()
        raise
    return cluster


@contextlib.contextmanager
def _start_signals_held(active: bool):
    """Ctrl-C and SIGTERM noted while the block (the embedded cluster's start) runs and handed
    to their handlers on leaving (:func:`facetransfer.signals.deferred_signals`), and Ctrl-C
    blocked meanwhile in this thread (``pthread_sigmask``): the threads and processes started
    in the block (the cluster's event loop and its threads, the workers and every process they
    start) inherit the block and never take a terminal's Ctrl-C, while one sent to this
    process waits, pending, until the block ends. Before, Ctrl-C was ignored (``SIG_IGN``) for
    the workers to inherit, and so was lost when it came as the cluster started: the run went
    on. Nothing when not ``active`` (worker threads) or outside the main thread; where signals
    cannot be blocked (not POSIX), Ctrl-C is ignored in the block, as before."""
    import signal
    import threading

    from ..signals import deferred_signals

    if not active or threading.current_thread() is not threading.main_thread():
        yield
        return
    if not hasattr(signal, "pthread_sigmask"):   # pragma: no cover (Windows)
        with deferred_signals((signal.SIGTERM,)):
            before = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                yield
            finally:
                signal.signal(signal.SIGINT, before)
        return
    # multiprocessing's resource tracker, started by the first worker's spawn, unblocks
    # Ctrl-C in the thread that starts it (the cluster's event loop), which then started the
    # workers with it: started here first (each spawn starts it, once, if not running)
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    with deferred_signals((signal.SIGINT, signal.SIGTERM)):
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:     # a Ctrl-C pending is delivered here, noted, and raised on leaving
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def scatter_model(client, model):
    """Send the model to every worker once; pass the returned future to the tasks. For a model
    built in memory only: on a scheduler whose active memory manager is on (a user's own, by
    default) the copies are reduced to one, lost with its worker (:mod:`.model_ref`).

    Returns
    -------
    distributed.Future
        Resolved to the model on each worker (not pickled with each task).
    """
    if model is None:
        return None
    return client.scatter(model, broadcast=True, hash=False)
