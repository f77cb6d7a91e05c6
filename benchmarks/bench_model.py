"""Benchmark of issue 2: data-set build cost, N-mode SVD / ALS against tensorly, separability.

Measures, in one run:

1. build time and peak memory (max RSS of a fresh subprocess) of ``ict-bilinear`` and
   ``ict-trilinear`` from the raw FaceKit files, without any cache;
2. N-mode SVD and ALS (HOOI) of :mod:`facetransfer.tensor` (vertex mode skipped) against
   ``tensorly.decomposition.partial_tucker`` over the attribute modes only, with the same ranks,
   on random-but-structured 90,000 × 10 × 15 and 90,000 × 5 × 5 × 16 tensors: time ratio and
   relative reconstruction error ``||T - T̂|| / ||T||`` (computed the same way for both);
3. separability (Vlasic et al. 2005, §4.3): hold out one identity of ``ict-bilinear``, build the
   model from the others, fit the held-out identity's weights to its neutral face (Eq. (9) basis,
   least squares), apply the expression weights of "smile" learnt from the others, and compare
   with its true deformation-transferred smile, relative to the smile's displacement norm.

Usage::

    OMP_NUM_THREADS=1 FACETRANSFER_DATA_DIR=... python benchmarks/bench_model.py [--out out/benchmarks]

Writes ``OUT/model.json`` and ``OUT/model.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


# ------------------------------------------------------------------------------ 1. builds
def _child_build(name: str) -> None:
    """Run in a fresh process: build without caches, print JSON with time and memory."""
    import facetransfer.datasets.ict as ict

    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.perf_counter()
    ds = ict.build_ict_dataset(name, use_cache=False)
    sec = time.perf_counter() - t
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"dataset": name, "seconds": sec, "shape": list(ds.vertices.shape),
                      "dataset_mb": ds.vertices.nbytes / 2**20,
                      "peak_rss_mb": rss / 1024, "rss_after_imports_mb": rss0 / 1024}))


def bench_builds() -> list[dict]:
    out = []
    for name in ("ict-bilinear", "ict-trilinear"):
        tmp = tempfile.mkdtemp(prefix="ftbench")
        env = dict(os.environ, XDG_CACHE_HOME=tmp)
        try:
            res = subprocess.run([sys.executable, __file__, "--child-build", name], env=env,
                                 capture_output=True, text=True, check=True)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        row = json.loads(res.stdout.strip().splitlines()[-1])
        print(f"build {name}: {row['seconds']:.1f} s, peak RSS {row['peak_rss_mb']:.0f} MB "
              f"(data set {row['dataset_mb']:.0f} MB)")
        out.append(row)
    return out


# ------------------------------------------------------------------------------ 2. tensors
def structured_tensor(shape, ranks, *, noise=0.05, seed=0) -> np.ndarray:
    """``G ×_1 U_1 ... ×_K U_K`` (attribute modes of multilinear rank ``ranks``, decaying spectra)
    plus Gaussian noise of relative size ``noise``; mode 0 is the huge 'vertex' mode."""
    from facetransfer.tensor import multi_mode_dot

    rng = np.random.default_rng(seed)
    core = rng.standard_normal((shape[0],) + tuple(ranks))
    for k, r in enumerate(ranks):
        decay = 1.0 / (1.0 + np.arange(r)) ** 0.7
        core *= decay.reshape((1,) * (k + 1) + (r,) + (1,) * (len(ranks) - k - 1))
    Us = [None] + [np.linalg.qr(rng.standard_normal((d, r)))[0] for d, r in zip(shape[1:], ranks)]
    T = multi_mode_dot(core, Us)
    T += noise * np.linalg.norm(T) / np.sqrt(T.size) * rng.standard_normal(T.shape)
    return T


def _rel_err(T, core, factors) -> float:
    from facetransfer.tensor import tucker_to_tensor

    R = tucker_to_tensor(core, factors)
    return float(np.linalg.norm(T - R) / np.linalg.norm(T))


def _best_of(fn, reps):
    best, res = np.inf, None
    for _ in range(reps):
        t = time.perf_counter()
        res = fn()
        best = min(best, time.perf_counter() - t)
    return best, res


def bench_tensors(reps: int = 3) -> list[dict]:
    import tensorly as tl
    from tensorly.decomposition import partial_tucker

    from facetransfer import tensor as ft

    tl.set_backend("numpy")
    cases = [((90_000, 10, 15), (6, 9)), ((90_000, 5, 5, 16), (4, 4, 16))]
    rows = []
    for shape, ranks in cases:
        T = structured_tensor(shape, tuple(max(1, r - 1) if r < d else r
                                           for d, r in zip(shape[1:], ranks)))
        modes = list(range(1, len(shape)))
        rk = [None] + list(ranks)
        n_sweeps = 10
        t_svd, ours_svd = _best_of(lambda: ft.nmode_svd(T, rk, skip=(0,)), reps)
        t_tl_svd, tl_svd = _best_of(lambda: partial_tucker(T, rank=list(ranks), modes=modes,
                                                           n_iter_max=0), reps)
        t_als, ours_als = _best_of(lambda: ft.hooi(T, rk, skip=(0,), max_iter=n_sweeps, tol=1e-8),
                                   reps)
        t_tl_als, tl_als = _best_of(lambda: partial_tucker(T, rank=list(ranks), modes=modes,
                                                           n_iter_max=n_sweeps, tol=1e-8), reps)
        e = {
            "ours_nmode_svd": _rel_err(T, ours_svd.core, ours_svd.factors),
            "tensorly_svd_init": _rel_err(T, tl_svd[0][0], [None] + list(tl_svd[0][1])),
            "ours_als": _rel_err(T, ours_als.core, ours_als.factors),
            "tensorly_als": _rel_err(T, tl_als[0][0], [None] + list(tl_als[0][1])),
        }
        row = {"shape": list(shape), "ranks": list(ranks), "reps": reps,
               "seconds": {"ours_nmode_svd": t_svd, "tensorly_svd_init": t_tl_svd,
                           "ours_als": t_als, "tensorly_als": t_tl_als},
               "rel_error": e,
               "als_sweeps": {"ours": len(ours_als.errors) - 1, "tensorly": len(tl_als[1])},
               "speedup_nmode_svd": t_tl_svd / t_svd, "speedup_als": t_tl_als / t_als}
        print(f"tensor {shape} ranks {ranks}: N-mode SVD {t_svd:.3f} s vs tensorly "
              f"{t_tl_svd:.3f} s ({row['speedup_nmode_svd']:.1f}x), err {e['ours_nmode_svd']:.6f} vs "
              f"{e['tensorly_svd_init']:.6f}; ALS {t_als:.3f} s vs {t_tl_als:.3f} s "
              f"({row['speedup_als']:.1f}x), err {e['ours_als']:.6f} vs {e['tensorly_als']:.6f}")
        rows.append(row)
        del T
    return rows


# ------------------------------------------------------------------------------ 3. separability
def _separability_one(ds, h: int, ranks: tuple[int, int], expression: str) -> dict:
    from facetransfer.model import build_model

    ids = list(ds.labels[0])
    keep = [i for i in range(len(ids)) if i != h]
    train = type(ds)(ds.vertices[keep], ds.mask[keep], ds.mode_names,
                     (tuple(ids[i] for i in keep), ds.labels[1]), ds.faces, ds.uvs, ds.landmarks,
                     ds.vertex_subset, dict(ds.provenance, holdout=ids[h]))
    m = build_model(train, {"identity": ranks[0], "expression": ranks[1]})
    e_neu, e_exp = ds.labels[1].index("neutral"), ds.labels[1].index(expression)
    true_neutral, true_expr = ds.vertices[h, e_neu], ds.vertices[h, e_exp]
    true_disp = true_expr - true_neutral
    w_neu = m.training_weights("expression", "neutral")
    w_exp = m.training_weights("expression", expression)
    # Eq. (9): with the expression fixed to "neutral" the model is linear in the identity weights
    B = m.mode_basis("identity", {"identity": m.weight_mean("identity"), "expression": w_neu})
    w_id, *_ = np.linalg.lstsq(B.reshape(-1, B.shape[-1]), true_neutral.ravel(), rcond=None)
    fit_neutral = m.synthesize({"identity": w_id, "expression": w_neu})
    pred = m.synthesize({"identity": w_id, "expression": w_exp})
    disp = np.linalg.norm(true_disp)
    generic = ds.vertices[ids.index("generic")]
    avg_offset = np.mean(ds.vertices[keep, e_exp] - ds.vertices[keep, e_neu], axis=0)
    return {
        "holdout": ids[h],
        "displacement_norm_cm": float(disp),
        "rel_error_total": float(np.linalg.norm(pred - true_expr) / disp),
        "rel_error_displacement": float(np.linalg.norm((pred - fit_neutral) - true_disp) / disp),
        "rel_error_neutral_fit": float(np.linalg.norm(fit_neutral - true_neutral) / disp),
        "baseline_generic_offsets": float(np.linalg.norm(generic[e_exp] - generic[e_neu] - true_disp) / disp),
        "baseline_mean_training_offsets": float(np.linalg.norm(avg_offset - true_disp) / disp),
    }


def bench_separability(expression: str = "smile",
                       rank_sets: tuple[tuple[int, int], ...] = ((9, 6), (9, 10))) -> dict:
    """Leave-one-identity-out over every sampled identity of ict-bilinear (not the generic one).

    Errors are relative to the held-out identity's true smile displacement norm
    ``||smile - neutral||_F``: ``total`` compares the synthesized smile with the true one;
    ``displacement`` compares synthesized smile minus synthesized neutral with the true
    displacement (removing the error of fitting the neutral face); the baselines add one
    displacement to every face (the generic face's, or the training identities' mean).
    """
    from facetransfer.datasets import build_ict_dataset

    ds = build_ict_dataset("ict-bilinear")
    out = {"expression": expression, "dataset": "ict-bilinear", "runs": {}}
    for ranks in rank_sets:
        rows = [_separability_one(ds, h, ranks, expression)
                for h in range(len(ds.labels[0])) if ds.labels[0][h] != "generic"]
        keys = [k for k in rows[0] if k not in ("holdout", "displacement_norm_cm")]
        summary = {k: {"mean": float(np.mean([r[k] for r in rows])),
                       "median": float(np.median([r[k] for r in rows])),
                       "max": float(np.max([r[k] for r in rows]))} for k in keys}
        label = f"identity={ranks[0]},expression={ranks[1]}"
        out["runs"][label] = {"summary": summary, "per_holdout": rows}
        print(f"separability ({expression}, leave-one-out over {len(rows)} identities, ranks {label}): "
              + ", ".join(f"{k} {v['mean']:.3f}" for k, v in summary.items()) + " (mean, relative)")
    return out


# ------------------------------------------------------------------------------ plot
def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, ax = plt.subplots(1, 3, figsize=(14, 4.2))
    b = result["builds"]
    ax[0].bar([r["dataset"] for r in b], [r["seconds"] for r in b], color="#4c72b0")
    for i, r in enumerate(b):
        ax[0].text(i, r["seconds"], f"{r['seconds']:.1f} s\n{r['peak_rss_mb']:.0f} MB", ha="center",
                   va="bottom", fontsize=8)
    ax[0].set_ylabel("seconds (cold, no cache)")
    ax[0].set_title("data-set build")
    t = result["tensors"]
    labels, ours, theirs = [], [], []
    for r in t:
        s = "x".join(map(str, r["shape"][1:]))
        for k, kt in (("ours_nmode_svd", "tensorly_svd_init"), ("ours_als", "tensorly_als")):
            labels.append(f"{s}\n{'HOSVD' if 'svd' in k else 'ALS'}")
            ours.append(r["seconds"][k])
            theirs.append(r["seconds"][kt])
    x = np.arange(len(labels))
    ax[1].bar(x - 0.2, ours, 0.4, label="facetransfer.tensor")
    ax[1].bar(x + 0.2, theirs, 0.4, label="tensorly partial_tucker")
    ax[1].set_xticks(x, labels, fontsize=8)
    ax[1].set_yscale("log")
    ax[1].set_ylabel("seconds (best of %d)" % t[0]["reps"])
    ax[1].set_title("90,000 x attribute modes, same ranks")
    ax[1].legend(fontsize=8)
    s = result["separability"]
    keys = ["rel_error_total", "rel_error_displacement", "rel_error_neutral_fit",
            "baseline_generic_offsets", "baseline_mean_training_offsets"]
    short = ["total", "displ.", "neutral fit", "generic offs.", "mean offs."]
    runs = list(s["runs"].items())
    x = np.arange(len(keys))
    for j, (label, run) in enumerate(runs):
        ax[2].bar(x + (j - (len(runs) - 1) / 2) * 0.38, [run["summary"][k]["mean"] for k in keys],
                  0.38, label=label)
    ax[2].set_xticks(x, short, fontsize=8)
    ax[2].set_ylabel("error / smile displacement norm (mean)")
    ax[2].set_title(f"separability: leave one identity out, {s['expression']}")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/benchmarks", help="output folder (default out/benchmarks)")
    p.add_argument("--reps", type=int, default=3, help="timing repetitions (best of)")
    p.add_argument("--parts", default="builds,tensors,separability",
                   help="comma-separated parts to run; others are kept from an existing model.json")
    p.add_argument("--child-build", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child_build:
        _child_build(a.child_build)
        return 0
    from facetransfer.io.atomic import write_text_atomic

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    parts = {x.strip() for x in a.parts.split(",") if x.strip()}
    unknown = parts - {"builds", "tensors", "separability"}
    if unknown:
        p.error(f"unknown --parts {sorted(unknown)}")
    old = out / "model.json"
    result = json.loads(old.read_text()) if old.is_file() and parts != {"builds", "tensors", "separability"} else {}
    result["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count(),
                         "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
                         "load_average_at_start": os.getloadavg()[0]}
    if "builds" in parts:
        result["builds"] = bench_builds()
    if "tensors" in parts:
        result["tensors"] = bench_tensors(a.reps)
    if "separability" in parts:
        result["separability"] = bench_separability()
    missing = {"builds", "tensors", "separability"} - set(result)
    if missing:
        p.error(f"no earlier results for {sorted(missing)} in {old}; run them too")
    write_text_atomic(out / "model.json", json.dumps(result, indent=2))
    plot(result, out / "model.png")
    print(f"wrote {out / 'model.json'} and {out / 'model.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
