"""What a ``batch transfer`` rerun's summary says of the pairs it keeps: the figures the run
that made them said (a video does not hold its target's confidence)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import test_batch  # noqa: E402
import test_batch_matte  # noqa: E402

# the batch tests' synthetic clips, in-process cluster, pairs and helpers, shared
clips, inproc, pairs = test_batch.clips, test_batch.inproc, test_batch_matte.pairs
_cli, _summary = test_batch._cli, test_batch._summary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_a_rerun_keeps_each_kept_pairs_mean_confidence(pairs, quick_model_path, inproc,
                                                       tmp_path, capsys):
    """A run's summary names each pair's target confidence; the same command again skips both
    pairs and its summary said nothing of it (the cell empty: a studio reading the summary of
    a run resumed after a Ctrl-C lost the figure of every pair done before it); now it keeps
    the figure the run that made the result said, row after row of reruns; a result replaced
    by other options is refused as before, with no figure."""
    man, _ = pairs
    out = tmp_path / "out"

    def batch(*more):
        return _cli(capsys, "batch", "transfer", "--manifest", man, "--model", quick_model_path,
                    "--out", out, "--workers", "1", "--no-progress", *more)

    assert batch()[0] == 0
    done = {n: r["mean_confidence"] for n, r in _summary(out / "summary.csv").items()}
    assert set(done) == {"ab", "ba"} and all(float(c) > 0.9 for c in done.values()), done
    for _ in range(2):
        code, said, err = batch()
        assert code == 0 and "(2 skipped)" in said, (said, err)
        rows = _summary(out / "summary.csv")
        assert {n: (r["status"], r["mean_confidence"]) for n, r in rows.items()} == \
            {n: ("skipped", c) for n, c in done.items()}
    code, said, err = batch("--crf", "30")                           # other options
    rows = _summary(out / "summary.csv")
    assert code == 1 and {r["status"] for r in rows.values()} == {"failed"}, (said, err)
    assert {r["mean_confidence"] for r in rows.values()} == {""}


def test_a_rerun_keeps_each_kept_takes_frames_rate_and_confidence(
        arkit_model, arkit_model_path, make_arkit_track, inproc, tmp_path, capsys):
    """``batch export`` to Live Link Face takes and JSON: the rows of a rerun that keeps them
    said nothing of their frames, rate or confidence (a take holds none of these as the row
    has them); now the figures the run that made them said."""
    import dataclasses

    import numpy as np

    tracks = []
    for n, (frames, fps) in enumerate(((9, 25.0), (6, 30.0))):
        t, _, _ = make_arkit_track(arkit_model, frames, seed=n, fps=fps)
        conf = np.linspace(0.5, 1.0, frames)
        tracks.append(dataclasses.replace(t, confidence=conf).save(tmp_path / f"t{n}.npz"))
    for fmt in ("livelink", "json"):
        out = tmp_path / fmt
        argv = ("batch", "export", *tracks, "--format", fmt, "--out", out, "--model",
                arkit_model_path, "--workers", "1", "--no-progress")
        assert _cli(capsys, *argv)[0] == 0
        cells = ("frames", "fps", "mean_confidence")
        done = {n: tuple(r[c] for c in cells) for n, r in _summary(out / "summary.csv").items()}
        assert done == {"t0": ("9", "25", "0.75"), "t1": ("6", "30", "0.75")}, done
        code, said, err = _cli(capsys, *argv)
        assert code == 0 and "(2 skipped)" in said, (said, err)
        assert {n: tuple(r[c] for c in cells) for n, r in
                _summary(out / "summary.csv").items()} == done
