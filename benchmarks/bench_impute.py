"""Benchmark of missing-data imputation (Vlasic et al. 2005, §4.4).

For each data set (default ``ict-trilinear`` and ``ict-bilinear``) and missing fraction
0.1 … 0.5, hides that fraction of the cells at random (never a whole slice), ``--trials`` times,
and predicts them with the paper's scheme (``ppca``) and the baselines (``average``: Blanz et al.
2003 generalised; ``naive``: §4.4's complete sub-tensor scheme; ``tensorly``: masked Tucker, the
external peer). Then times ``impute_dataset(..., method="ppca")`` end to end on the largest data set
with 50 % of its cells missing.

Writes ``OUT/impute.json`` and ``OUT/impute.png``. Targets (issue 3): paper < 9 % error up to 50 %
missing; ours < 5 % at 50 % on ict-trilinear and below every baseline at every fraction; 50 %
missing imputed in < 30 s on 2 cores.

Usage::

    FACETRANSFER_DATA_DIR=/tmp/ftdata python benchmarks/bench_impute.py --out out/benchmarks
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np


def _timing(ds, fraction: float, seed: int, repeats: int = 3) -> dict:
    """End-to-end time of ``impute_dataset(method="ppca")`` with ``fraction`` of cells missing."""
    from facetransfer.datasets import FaceDataset
    from facetransfer.impute import impute_dataset, random_holdout

    held = random_holdout(ds.mask, fraction, np.random.default_rng([seed, 12345]))
    verts = ds.vertices.copy()
    verts[held] = np.nan
    inc = FaceDataset(verts, ds.mask & ~held, ds.mode_names, ds.labels, ds.faces, ds.uvs,
                      ds.landmarks, ds.vertex_subset, dict(ds.provenance))
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = impute_dataset(inc, method="ppca")
        times.append(time.perf_counter() - t0)
    return {"fraction": fraction, "cells_missing": int(held.sum()), "cells": int(held.size),
            "rows": 3 * ds.n_vertices, "seconds": times, "seconds_min": min(times),
            "iterations": res.iterations, "converged": res.converged,
            "threads": os.environ.get("OMP_NUM_THREADS", "default")}


def _mouth_study(ds, fractions=(0.15, 0.5), trials=3, seed=0) -> dict:
    """§4.4: "the averaging scheme seems to do a better job at keeping the lips sealed for
    closed-mouth faces ... We could obtain better results by preferentially weighting detail
    around the mouth". For held-out closed-mouth cells (viseme ``man``, the m-viseme), the error
    of the inner-lip gap (iBUG 61-67, 62-66, 63-65) relative to the outer eye-corner distance, and
    the mouth-region error, for ppca, ppca with mouth regions, ppca with 8 regions and averaging."""
    from facetransfer import impute as im

    if ds.landmarks is None or "viseme" not in ds.mode_names:
        return {}
    T = ds.data_tensor()
    P, shape, n = T.shape[0], ds.shape, ds.n_vertices
    vi = ds.mode_names.index("viseme")
    labels = [l.lower() for l in ds.labels[vi]]
    closed = labels.index("man") if "man" in labels else 0
    lm = ds.landmarks
    mean = ds.vertices[ds.mask].mean(axis=0)
    eye = float(np.linalg.norm(mean[lm[36]] - mean[lm[45]]))
    mouth = np.linalg.norm(mean - mean[lm[48:68]].mean(axis=0), axis=1) < 0.35 * eye
    pairs = [(61, 67), (62, 66), (63, 65)]

    def gap(V):
        return np.stack([np.linalg.norm(V[..., lm[a], :] - V[..., lm[b], :], axis=-1)
                         for a, b in pairs], -1)

    ref = im.reference_indices(ds.mode_names, ds.labels, shape)
    Vt = np.moveaxis(T, 0, -1).reshape(shape + (n, 3))
    neutral = Vt[(slice(None),) + ref][:, None, None]
    memb = {"ppca-mouth": im.dataset_regions(ds, "mouth"),
            "ppca-regions8": im.dataset_regions(ds, 8)}
    out = {"closed_viseme": ds.labels[vi][closed], "eye_distance": eye,
           "mouth_vertices": int(mouth.sum()), "results": []}
    for f in fractions:
        acc: dict[str, list] = {}
        for t in range(trials):
            held = im.random_holdout(ds.mask, f, np.random.default_rng([seed, t, 777]))
            mask = ds.mask & ~held
            Tin = T.copy()
            Tin[:, ~mask] = np.nan
            hc = held.copy()
            hc[(slice(None),) * vi + (np.arange(shape[vi]) != closed,)] = False
            for m in ("ppca", "ppca-mouth", "ppca-regions8", "average"):
                if m in memb:
                    fill = im.impute_tensor_by("ppca", Tin, mask, memberships=memb[m]).tensor
                else:
                    fill = im.impute_tensor_by(m, Tin, mask).tensor
                Vo = np.moveaxis(fill, 0, -1).reshape(shape + (n, 3))
                disp = (Vt - neutral)[held][:, mouth]
                acc.setdefault(m, []).append((
                    float(np.abs(gap(Vo[hc]) - gap(Vt[hc])).mean() / eye),
                    float(np.linalg.norm((Vo - Vt)[held][:, mouth]) / np.linalg.norm(disp)),
                    float(np.linalg.norm((fill - T)[:, held]) / np.linalg.norm(T))))
        for m, v in acc.items():
            v = np.array(v)
            out["results"].append({"method": m, "missing": f,
                                   "closed_lip_gap_error": v[:, 0].mean(),
                                   "mouth_relative_error": v[:, 1].mean(),
                                   "error_mean": v[:, 2].mean()})
    return out


def _plot(all_results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    names = list(all_results)
    fig, axes = plt.subplots(len(names), 2, figsize=(10, 3.8 * len(names)), squeeze=False)
    for row, name in enumerate(names):
        res = all_results[name]
        for m in dict.fromkeys(r["method"] for r in res):
            rs = sorted((r for r in res if r["method"] == m), key=lambda r: r["missing"])
            x = [100 * r["missing"] for r in rs]
            axes[row, 0].plot(x, [100 * r["error_mean"] for r in rs], "o-", label=m)
            axes[row, 1].plot(x, [100 * r["relative_error_mean"] for r in rs], "o-", label=m)
        axes[row, 0].axhline(9, color="gray", ls="--", lw=1, label="paper: < 9 %")
        axes[row, 0].axhline(5, color="k", ls=":", lw=1, label="target: < 5 %")
        axes[row, 0].set_ylabel("error / ||data set|| (%)")
        axes[row, 1].set_ylabel("error / ||held-out displacement|| (%)")
        for ax in axes[row]:
            ax.set_title(name)
            ax.set_xlabel("missing cells (%)")
            ax.set_yscale("log")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle("§4.4 imputation of held-out faces: ours (ppca) vs baselines")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--datasets", default="ict-trilinear,ict-bilinear")
    ap.add_argument("--missing", default="0.1,0.2,0.3,0.4,0.5")
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", default="ppca,average,naive,tensorly,ppca-mouth")
    ap.add_argument("--no-mouth-study", action="store_true")
    args = ap.parse_args(argv)

    from tqdm import tqdm

    from facetransfer.datasets import load_dataset
    from facetransfer.impute import evaluate_imputation
    from facetransfer.io.atomic import write_text_atomic

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fractions = [float(f) for f in args.missing.split(",")]
    methods = args.methods.split(",")
    report = {"benchmark": "impute", "paper": "Vlasic et al. 2005, §4.4",
              "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS")},
              "trials": args.trials, "seed": args.seed, "datasets": {}}
    all_results = {}
    for name in args.datasets.split(","):
        ds = load_dataset(name)
        bar = tqdm(total=len(fractions) * args.trials * len(methods), desc=name, unit="run",
                   disable=not sys.stderr.isatty())  # no bar drawn into a log file
        t0 = time.perf_counter()
        ev = evaluate_imputation(ds, fractions, trials=args.trials, seed=args.seed,
                                 methods=methods, progress=lambda m: bar.update(1))
        bar.close()
        res = [{"method": r.method, "missing": r.missing, "error_mean": r.error_mean,
                "error_max": r.error_max, "relative_error_mean": r.relative_error_mean,
                "seconds": r.seconds, "errors": list(r.errors),
                "relative_errors": list(r.relative_errors)} for r in ev.results]
        all_results[name] = res
        by = {(r["method"], r["missing"]): r for r in res}
        checks = {}
        if "ppca" in methods:
            others = [m for m in methods if m in ("average", "naive", "tensorly")]
            checks["ppca_below_every_baseline_every_fraction"] = all(
                by[("ppca", f)][k] < by[(m, f)][k] for f in fractions for m in others
                for k in ("error_mean", "relative_error_mean"))
            checks["ppca_error_at_max_fraction"] = by[("ppca", max(fractions))]["error_mean"]
            checks["paper_target_below_9_percent"] = all(
                by[("ppca", f)]["error_max"] < 0.09 for f in fractions if f <= 0.5)
            checks["our_target_below_5_percent_at_50"] = (
                by[("ppca", 0.5)]["error_mean"] < 0.05 if ("ppca", 0.5) in by else None)
        print(f"\n{name} {tuple(ds.shape)} x {3 * ds.n_vertices} rows "
              f"({time.perf_counter() - t0:.0f} s)")
        for r in res:
            print(f"  {r['method']:9s} {100 * r['missing']:3.0f} %: "
                  f"error {100 * r['error_mean']:7.3f} %"
                  f" (max {100 * r['error_max']:7.3f} %), relative "
                  f"{100 * r['relative_error_mean']:6.2f} %, {r['seconds']:6.2f} s")
        report["datasets"][name] = {"cells": list(ds.shape), "rows": 3 * ds.n_vertices,
                                    "results": res, "checks": checks}
    first = args.datasets.split(",")[0]
    ds = load_dataset(first)
    if not args.no_mouth_study:
        ms = _mouth_study(ds, seed=args.seed)
        report["mouth_study"] = ms
        for r in ms.get("results", []):
            print(f"  mouth study {r['method']:14s} {100 * r['missing']:3.0f} %: closed-lip gap "
                  f"error {1000 * r['closed_lip_gap_error']:.2f}e-3 eye dist, mouth relative "
                  f"{100 * r['mouth_relative_error']:.2f} %, error {100 * r['error_mean']:.3f} %")
    report["timing_ppca_50"] = {"dataset": first, **_timing(ds, 0.5, args.seed)}
    t = report["timing_ppca_50"]
    report["timing_ppca_50"]["target_below_30_s"] = t["seconds_min"] < 30
    print(f"\nppca, {first}, 50 % missing: {t['seconds_min']:.2f} s "
          f"({t['iterations']} iterations, converged {t['converged']})")
    write_text_atomic(out / "impute.json", json.dumps(report, indent=2) + "\n")
    _plot(all_results, out / "impute.png")
    print(f"wrote {out / 'impute.json'} and {out / 'impute.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
