"""``batch --scheduler ADDRESS --timeout S`` over tcp:// and tls://
(:mod:`facetransfer.batch.cluster`): a host whose lookup hangs, one that cannot be resolved, an unroutable one, tls:// without
certificates, each one line within the timeout; a TLS scheduler reached by its host name."""

from __future__ import annotations

import os
import sys

import pytest

from facetransfer.batch import cluster as batch_cluster

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

#: The CLI in a child process, which then prints the threads it has left (the test does not
#: hang if the run does: the child is killed after the test's bound).
_CHILD = ("import sys, threading; from facetransfer.cli.main import main; code = main(sys.argv[1:])"
          "; print('threads', sorted(t.name for t in threading.enumerate())); sys.exit(code)")


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory):
    """A certificate authority and one certificate of it for every role (``openssl``)."""
    import shutil
    import subprocess

    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    d = tmp_path_factory.mktemp("tls")
    for argv in (["req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out",
                  "ca.pem", "-days", "2", "-subj", "/CN=test-ca"],
                 ["req", "-newkey", "rsa:2048", "-nodes", "-keyout", "k.key", "-out", "k.csr",
                  "-subj", "/CN=localhost"],
                 ["x509", "-req", "-in", "k.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                  "-CAcreateserial", "-out", "k.pem", "-days", "2"]):
        subprocess.run(["openssl", *argv], cwd=d, check=True, capture_output=True, timeout=60)
    return {"ca-file": str(d / "ca.pem"), "client.cert": str(d / "k.pem"),
            "client.key": str(d / "k.key")}


#: :data:`_CHILD` with a name server that never answers for ``dns-hangs.example``.
_CHILD_DNS = ("import socket, threading; real = socket.getaddrinfo; socket.getaddrinfo = "
              "lambda host, *a, **k: threading.Event().wait() if host == 'dns-hangs.example' "
              "else real(host, *a, **k)\n" + _CHILD)


def _child_run(tmp_path, argv, env=None):
    """The CLI in a child process with a name server that hangs for one name; its result."""
    import os
    import subprocess

    base = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    return subprocess.run([sys.executable, "-c", _CHILD_DNS, *map(str, argv)],
                          capture_output=True, text=True, timeout=60,
                          env={**base, "DASK_CONFIG": str(tmp_path / "no-dask-config"),
                               **(env or {})})


@pytest.mark.parametrize("proto", ["tcp", "tls"])
@pytest.mark.parametrize("host, said", [
    ("dns-hangs.example", ": the host 'dns-hangs.example' was not found within 2 s (a name "
     "server that does not answer?); check the address, or give the scheduler's IP address"),
    ("no-such-host.invalid", ": the host 'no-such-host.invalid' "),
    ("10.255.255.1", ""),
])
def test_an_address_that_does_not_answer_is_one_line_within_the_timeout(
        proto, host, said, tls_files, tmp_path):
    """A host whose lookup hangs (the name server does not answer: the run waited for as long
    as the lookup, 40 s measured of one that takes 40 s, for ever of one that never ends),
    one that cannot be resolved, an unroutable one; over tcp:// and tls:// (with this
    client's certificates in Dask's configuration: without them, the next test): one line
    naming the address, exit status 2, before the test's bound of 60 s."""
    addr = f"{proto}://{host}:8786"
    env = {f"DASK_DISTRIBUTED__COMM__TLS__{k.upper().replace('.', '__').replace('-', '_')}": v
           for k, v in tls_files.items()}
    r = _child_run(tmp_path, ["batch", "export", tmp_path / "t.npz", "--format", "json",
                              "--out", tmp_path / "o", "--scheduler", addr, "--timeout", "2"],
                   env)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"facetransfer batch export: error: no Dask scheduler answered at {addr}{said}"), lines
    assert not (tmp_path / "o").exists()


def test_a_tls_address_without_certificates_is_said_before_any_wait(tmp_path):
    """tls:// without the client's certificates in Dask's configuration: said at once, before
    the host is looked up (before: Dask's "TLS expects a `ssl_context` argument of type
    ssl.SSLContext ... Instead got None")."""
    addr = "tls://dns-hangs.example:8786"
    r = _child_run(tmp_path, ["batch", "export", tmp_path / "t.npz", "--format", "json",
                              "--out", tmp_path / "o", "--scheduler", addr, "--timeout", "30"])
    assert r.returncode == 2 and r.stderr.splitlines() == [
        f"facetransfer batch export: error: --scheduler {addr}: tls:// needs this client's "
        "certificates in Dask's configuration (distributed.comm.tls.ca-file, .client.cert and "
        ".client.key, e.g. DASK_DISTRIBUTED__COMM__TLS__CA_FILE=...), and none are set; give "
        "them, or the scheduler's tcp:// address"]
    assert r.stdout.splitlines() == ["threads ['MainThread']"]   # nothing was looked up


def test_a_tls_scheduler_is_reached_by_its_host_name(tls_files):
    """A scheduler over TLS, given by a host name: asked (its TLS handshake within the
    timeout) and connected to at the IP address the name resolved to."""
    import dask
    from dask.distributed import LocalCluster
    from distributed.security import Security

    cert, key = tls_files["client.cert"], tls_files["client.key"]
    sec = Security(tls_ca_file=tls_files["ca-file"], tls_scheduler_cert=cert,
                   tls_scheduler_key=key, tls_worker_cert=cert, tls_worker_key=key,
                   tls_client_cert=cert, tls_client_key=key, require_encryption=True)
    config = {f"distributed.comm.tls.{k}": v for k, v in tls_files.items()}
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tls",
                      security=sec, dashboard_address=None) as running, dask.config.set(config):
        port = running.scheduler_address.rsplit(":", 1)[1]
        by_name = f"tls://localhost:{port}"
        assert batch_cluster._probe(by_name, 5).startswith("tls://")
        with batch_cluster.open_client(scheduler=by_name, timeout=5) as client:
            assert client.submit(int, "7").result() == 7


def test_a_tls_address_of_a_plain_scheduler_is_said_as_a_refusal_not_a_wait(tls_files):
    """tls:// of a scheduler that speaks plain TCP: said as the connection it closed, at once,
    not as a wait for an answer ("... within 5 s")."""
    import dask
    from dask.distributed import LocalCluster

    config = {f"distributed.comm.tls.{k}": v for k, v in tls_files.items()}
    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None,
                      host="127.0.0.1") as running, dask.config.set(config):
        port = running.scheduler_address.rsplit(":", 1)[1]
        with pytest.raises(batch_cluster.BatchError) as err:
            batch_cluster._probe(f"tls://127.0.0.1:{port}", 5)
    said = str(err.value)   # the server closes the connection, or its bytes are not TLS's
    assert said.startswith(f"no Dask scheduler answered at tls://127.0.0.1:{port}: something "
                           "there "), said
    assert "within" not in said, said
    assert "not in Dask's protocol" in said or "closed them" in said, said


def test_a_sigterm_while_the_cluster_starts_is_raised_once_it_is_whole_and_closes_it(
        monkeypatch):
    """A SIGTERM (``kill``, ``timeout``) in the seconds the embedded cluster takes to start was
    raised inside its start: the half-started cluster's close at the exit and its workers'
    start printed tracebacks. It is now raised once the cluster is whole, which is closed."""
    import signal

    import dask.distributed

    from facetransfer.batch import cluster as cluster_mod
    from facetransfer.cli.main import Terminated, _terminated

    events = []

    class Starting:
        def __init__(self, **kw):
            os.kill(os.getpid(), signal.SIGTERM)    # while the workers start
            events.append("started")

        def close(self):
            events.append("closed")

    monkeypatch.setattr(dask.distributed, "LocalCluster", Starting)
    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        with pytest.raises(Terminated):
            cluster_mod._local_cluster(2, True, False)
    finally:
        signal.signal(signal.SIGTERM, before)
    assert events == ["started", "closed"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


#: The CLI (as the console script runs it) in a child process that sends a terminal's Ctrl-C
#: (SIGINT to every process of its group) at one moment of the embedded cluster's start, the
#: first argument: as the scheduler starts, as a worker process has just been started
#: (importing), or once the cluster is whole (before :func:`batch_cluster.open_client`
#: returns).
_CHILD_CTRL_C = """
import os, signal, sys
moment = sys.argv.pop(1)


def ctrl_c():
    os.killpg(0, signal.SIGINT)


if moment == "scheduler":
    from distributed.deploy import spec
    real_start = spec.SpecCluster._start

    async def start(self):
        ctrl_c()
        return await real_start(self)
    spec.SpecCluster._start = start
elif moment == "worker":
    import multiprocessing.process
    real_process = multiprocessing.process.BaseProcess.start

    def process_start(self):
        real_process(self)
        ctrl_c()
    multiprocessing.process.BaseProcess.start = process_start
else:
    import distributed
    real_init = distributed.LocalCluster.__init__

    def init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        ctrl_c()
    distributed.LocalCluster.__init__ = init
from facetransfer.cli.main import main
sys.exit(main())
"""


def _group_left(pgid: int) -> list[str]:
    """The processes of group ``pgid`` still running (not zombies, which init reaps)."""
    left = []
    for stat in os.listdir("/proc"):
        try:
            with open(f"/proc/{stat}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            left.append(stat)
    return left


@pytest.fixture(scope="module")
def clip_a(quick_model, tmp_path_factory):
    """An 8-frame synthetic clip and its first frame's points."""
    from conftest import clip_with_points

    d = tmp_path_factory.mktemp("ctrlc")
    return clip_with_points(quick_model, 8, 3, d, video="a.mp4", points="a.json")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("moment", ["scheduler", "worker", "whole"])
def test_a_ctrl_c_while_the_cluster_starts_stops_the_run(moment, clip_a, quick_model_path,
                                                         tmp_path):
    """A Ctrl-C in the seconds the embedded cluster takes to start (its workers started with
    Ctrl-C ignored, and so was the client while they started) was lost: the run went on to
    "1 done", exit 0. It is now held until the cluster is whole, which is closed: one line,
    exit 130, no worker left, nothing of Dask's left in the temporary folder but the two
    lock files every run leaves, no output folder."""
    import subprocess
    import time

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    env.update(TMPDIR=str(tmp), DASK_CONFIG=str(tmp_path / "no-dask-config"))
    out = tmp_path / "out"
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD_CTRL_C, moment, "batch", "track", str(clip_a[0]),
         "--init", str(clip_a[1]), "--model", str(quick_model_path), "--out", str(out),
         "--workers", "2", "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        start_new_session=True)
    try:
        stdout, stderr = child.communicate(timeout=180)
        deadline = time.monotonic() + 30     # a bound, not a measure: the workers are closed
        while _group_left(child.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _group_left(child.pid) == []
    finally:
        for pid in _group_left(child.pid):
            os.kill(int(pid), 9)
        child.kill()
    assert (child.returncode, stderr.splitlines(), stdout) == (
        130, ["facetransfer batch track: interrupted"], "")
    assert not out.exists()
    left = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*"))
    assert set(left) <= {"dask-scratch-space", "dask-scratch-space/global.lock",
                         "dask-scratch-space/purge.lock"}, left
