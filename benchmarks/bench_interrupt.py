"""Ctrl-C at any moment: what `transfer`, `track` and `puppet` do when interrupted, and whether
the next run continues to the same output.

Each command runs on a short real clip of the data folder (``--frames``, default 30), each run
a fresh process in its own session and process group, with a private user cache (its own track
and render caches; the default model linked in), as a terminal runs it. First one run left
alone (the reference, its time ``T``, the least of two runs); then, at ``--singles`` moments
evenly from 0.05 s to ``T``, a run sent SIGINT to its process group at that moment (a
terminal's Ctrl-C: the command and every process it started get it), and at ``--pairs``
moments a run sent two SIGINTs each of ``--gaps`` apart (a user pressing Ctrl-C again while the
program exits). Each interrupted run is checked, a fault for each failing check:

- ``start``: (not the program's) the signal came in Python's own start, before the program's
  first line ran: Python's traceback or its death by the signal, as for any Python program;
- ``status``: exit status 130 (the CLI's for an interrupt, ``facetransfer.cli.main``);
- ``lines``: exactly one line on stderr, the CLI's own (no traceback, no library's log line);
- ``hang``: it ends within ``--timeout`` seconds of the signal (else killed);
- ``orphan``: no process of its group is left running a second after it ended;
- ``partial``: no output at the output path unless the line says it had written it (then it is
  the whole output);
- ``temp``: no temporary file (``.NAME.PID-RANDOM.part*``) beside the output after the next run;
- ``resume``: the same command run again ends with status 0 and one line at most on stderr,
  and its output matches the reference: identical, or (``close``) within the documented
  difference of a tracking resumed mid-clip (MediaPipe's state: video PSNR of at least
  ``--min-psnr`` dB, track points within 1.5 px).

A run that finished before its moment came, or ended with status 0 and its whole output (the
signal came once its work was done), is counted as ``finished`` (no fault to find).
Videos are written with ``--crf 0`` so that a resumed render decodes to the same frames. No
peer: the tools this project compares with do not resume interrupted jobs.

Usage::

    python benchmarks/bench_interrupt.py --out out/benchmarks [--commands transfer,track]

Writes ``OUT/interrupt.json`` and prints the table of faults per command.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# benchmarks/ is on sys.path
from _report import arguments, save_json

DATA = Path(os.environ.get("FACETRANSFER_DATA_DIR", "../shared/data")) / "video"
#: The console script, run by this Python (the source tree on PYTHONPATH decides which; before
#: the fifty-fourth session its entry was ``facetransfer.cli.main:main``).
ENTRY = ("import sys\ntry:\n    from facetransfer.__main__ import main\n"
         "except ModuleNotFoundError:\n    from facetransfer.cli.main import main\n"
         "sys.exit(main())")
#: The one line an interrupted command says (the CLI's own, facetransfer.cli.main._run).
STOP_LINE = re.compile(r"^facetransfer( [\w-]+)?: interrupted")
TEMP = re.compile(r"^\..+\.\d+-[^.]+\.part")


def commands(frames: int) -> dict:
    """Each command's arguments (``{out}`` for its output path) and its output's kind."""
    crf = ["--crf", "0", "--no-progress", "--max-frames", str(frames)]
    return {
        "transfer": (["transfer", "--target", str(DATA / "driving_d9.mp4"), "--expression-from",
                      str(DATA / "driving_d6.mp4"), *crf, "--out", "{out}"], "out.mp4"),
        "track": (["track", str(DATA / "face_2.mp4"), "--no-progress", "--max-frames",
                   str(frames), "--out", "{out}"], "out.npz"),
        "puppet": (["puppet", str(DATA / "WDA_KatieHill_000.mp4"), *crf, "--out", "{out}"],
                   "out.mp4"),
        # long enough for the detection's second process (video_detect.SPLIT_MIN_FRAMES)
        "track-long": (["track", str(DATA / "driving_d6.mp4"), "--no-progress", "--max-frames",
                        str(max(frames, 240)), "--out", "{out}"], "out.npz"),
    }


def fresh_home(root: Path) -> Path:
    """A folder with an empty user cache of its own (the default model linked in)."""
    home = Path(tempfile.mkdtemp(dir=root))
    (home / "cache" / "facetransfer").mkdir(parents=True)
    models = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "facetransfer"
    (home / "cache" / "facetransfer" / "models").symlink_to(models / "models")
    return home


def launch(argv: list[str], home: Path) -> subprocess.Popen:
    """The command in its own session, Ctrl-C at its default (a shell's background job starts
    with it ignored), its user cache in ``home``."""
    env = {**os.environ, "XDG_CACHE_HOME": str(home / "cache")}
    return subprocess.Popen([sys.executable, "-c", ENTRY, *argv], env=env, cwd=home,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def group_left(pgid: int) -> list[str]:
    """The processes of the group ``pgid`` still running (``ps`` lines; a zombie is not one:
    a child the command did not wait for, gone once init reaps it)."""
    ps = subprocess.run(["ps", "-o", "pid=,stat=,args=", "-g", str(pgid)], capture_output=True,
                        text=True).stdout.splitlines()
    return [line.strip() for line in ps if not line.split()[1].startswith("Z")]


def run(argv: list[str], home: Path, at=(), timeout: float = 60.0) -> dict:
    """Run ``argv`` with SIGINT to its group at each moment of ``at`` (seconds from its start):
    its status, stderr lines, seconds, whether it hung or left processes."""
    t0 = time.perf_counter()
    p = launch(argv, home)
    sent, hung = 0, False
    for moment in at:
        try:
            p.wait(max(0.0, moment - (time.perf_counter() - t0)))
            break
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGINT)
            sent += 1
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        hung = True
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
    seconds = time.perf_counter() - t0
    deadline = time.monotonic() + 1.0
    while (orphan := group_left(p.pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    if orphan:
        os.killpg(p.pid, signal.SIGKILL)
    return {"status": p.returncode, "sent": sent, "hung": hung, "orphan": orphan,
            "seconds": round(seconds, 2), "stderr": err.splitlines(), "stdout": out.splitlines()}


def frames_of(path: Path) -> np.ndarray:
    """A video's decoded frames."""
    from facetransfer.io.video import read_video

    return np.asarray(read_video(path)[0])


def compare(path: Path, ref: Path, min_psnr: float) -> tuple[str, float]:
    """``(same | close | differs, measure)``: a video's PSNR (inf where identical) or a track's
    largest point difference in pixels against the reference's."""
    if not path.is_file():
        return "missing", float("nan")
    if path.suffix == ".npz":
        a, b = np.load(path), np.load(ref)
        if all(np.array_equal(a[k], b[k]) for k in b.files):
            return "same", 0.0
        d = float(np.abs(a["landmarks2d"] - b["landmarks2d"]).max())
        return ("close" if d <= 1.5 else "differs"), d
    a, b = frames_of(path), frames_of(ref)
    if a.shape != b.shape:
        return "differs", float("nan")
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    if mse == 0:
        return "same", float("inf")
    psnr = 10 * np.log10(255.0 ** 2 / mse)
    return ("close" if psnr >= min_psnr else "differs"), round(psnr, 1)


def faults_of(first: dict, again: dict | None, leftovers: list, kept: str) -> list[str]:
    """The checks an interrupted run (``first``) and its next run (``again``) failed."""
    faults = []
    if first["status"] in (1, -signal.SIGINT) and not any(
            "<string>" in line or "facetransfer" in line for line in first["stderr"]):
        return ["start"]     # in Python's own start, before the program's first line ran
    if first["hung"]:
        faults.append("hang")
    if first["status"] != 130 and not first["hung"]:
        faults.append("status")
    if len(first["stderr"]) != 1 or not STOP_LINE.match(first["stderr"][0]):
        faults.append("lines")
    if first["orphan"]:
        faults.append("orphan")
    if kept == "partial":
        faults.append("partial")
    if leftovers:
        faults.append("temp")
    if again is None or again["status"] != 0 or len(again["stderr"]) > 1 or \
            again.get("verdict") not in ("same", "close"):
        faults.append("resume")
    return faults


def trial(spec, kind: str, root: Path, at: tuple, ref: Path, opts) -> dict:
    """One interrupted run at the moments ``at`` and the same command run again."""
    home = fresh_home(root)
    out = home / "outdir" / kind
    out.parent.mkdir()
    argv = [a.replace("{out}", str(out)) for a in spec]
    first = run(argv, home, at, opts.timeout)
    row = {"at": [round(a, 3) for a in at], "first": first}
    if first["status"] == 0 and (first["sent"] == 0 or compare(out, ref, opts.min_psnr)[0]
                                 in ("same", "close")):
        row["result"] = "finished"     # before its moment, or the signal came after its work
        shutil.rmtree(home, ignore_errors=True)
        return row
    said = " ".join(first["stderr"])
    kept = "none"
    if out.exists():
        kept = "written" if "had written" in said and compare(out, ref, opts.min_psnr)[0] \
            in ("same", "close") else "partial"
    again = run(argv + (["--overwrite"] if out.exists() else []), home, (), opts.timeout)
    again["verdict"], again["measure"] = compare(out, ref, opts.min_psnr)
    leftovers = [p.name for p in out.parent.iterdir() if TEMP.match(p.name)]
    row.update(again=again, kept=kept, leftovers=leftovers,
               faults=faults_of(first, again, leftovers, kept))
    row["result"] = "start" if row["faults"] == ["start"] else \
        "fault" if row["faults"] else "ok"
    shutil.rmtree(home, ignore_errors=True)
    return row


def reference(name: str, spec, kind: str, root: Path, opts) -> tuple[Path, float]:
    """The command left alone (twice: its output must not change between runs): the output
    kept for comparison and the first run's seconds."""
    outs, seconds = [], []
    for _ in range(2):
        home = fresh_home(root)
        out = root / f"reference-{len(outs)}-{name}-{kind}"
        got = run([a.replace("{out}", str(out)) for a in spec], home, (), 600.0)
        if got["status"] != 0:
            raise SystemExit(f"the reference run failed: {got['stderr'][-3:]}")
        outs.append(out)
        seconds.append(got["seconds"])
        shutil.rmtree(home, ignore_errors=True)
    verdict = compare(outs[1], outs[0], opts.min_psnr)
    if verdict[0] != "same":
        print(f"  note: two uninterrupted runs differ ({verdict})", flush=True)
    return outs[0], min(seconds)


def moments(seconds: float, opts) -> list[tuple]:
    """The moments to interrupt at: ``--singles`` single ones evenly from 0.05 s to the
    reference's time, and ``--pairs`` moments evenly from 0.1 s, each with a second SIGINT
    each of ``--gaps`` later."""
    if opts.at:
        return [tuple(float(t) for t in a.split("+")) for a in opts.at.split(",")]
    singles = [(round(float(t), 3),) for t in np.linspace(0.05, seconds, opts.singles)]
    gaps = [float(g) for g in opts.gaps.split(",")]
    doubles = [(round(float(t), 3), round(float(t) + g, 3))
               for t in np.linspace(0.1, seconds, opts.pairs) for g in gaps]
    return singles + doubles


def measure(name: str, opts, root: Path) -> dict:
    """Every moment's trial of the command ``name``."""
    spec, kind = commands(opts.frames)[name]
    ref, seconds = reference(name, spec, kind, root, opts)
    print(f"{name}: reference {seconds:.1f} s", flush=True)
    rows = []
    for at in moments(seconds, opts):
        row = trial(spec, kind, root, at, ref, opts)
        rows.append(row)
        note = ",".join(row.get("faults", [])) or row["result"]
        print(f"  {name} at {row['at']}: {note}", flush=True)
        if row.get("faults"):
            print("    stderr: " + " | ".join(row["first"].get("stderr", [])[-6:])[:1500],
                  flush=True)
    return {"reference_seconds": seconds, "trials": rows}


def table(report: dict) -> str:
    """Per command: the moments tried, those finished first, and the faults of each check."""
    checks = ("start", "status", "lines", "hang", "orphan", "partial", "temp", "resume")
    head = "| command | moments | finished first | faulty | " + " | ".join(checks) + " |"
    lines = [head, "|" + "---|" * (4 + len(checks))]
    for name, r in report["commands"].items():
        rows = r["trials"]
        counts = [sum(c in t.get("faults", []) for t in rows) for c in checks]
        lines.append(f"| {name} | {len(rows)} | {sum(t['result'] == 'finished' for t in rows)} "
                     f"| {sum(t['result'] == 'fault' for t in rows)} | "
                     + " | ".join(map(str, counts)) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--commands", default="transfer,track,puppet,track-long")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--singles", type=int, default=30)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--gaps", default="0.01,0.05,0.2")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--min-psnr", type=float, default=40.0)
    ap.add_argument("--at", default="", help="these moments only: 1.2,0.5+0.55 (a pair)")
    opts = ap.parse_args()
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    report = {"frames": opts.frames, "singles": opts.singles, "pairs": opts.pairs,
              "gaps": opts.gaps, "commands": {}}
    with tempfile.TemporaryDirectory(prefix="interrupt-") as tmp:
        for name in opts.commands.split(","):
            report["commands"][name] = measure(name, opts, Path(tmp))
            save_json(report, out / "interrupt.json")
    print(table(report))


if __name__ == "__main__":
    main()
