"""Fit reports: surface-distance statistics (JSON) and a picture coloured by distance (PNG)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..io.atomic import save_figure, write_text_atomic
from .fitting import FitResult
from .procrustes import Similarity


def fit_report(result: FitResult, *, scan: str = "", features: str = "", template: str = "",
               credit: str | None = None, repairs=()) -> dict:
    """A JSON-ready summary of a fit: distance statistics (scan units), timing and history;
    ``repairs``: what cleaning the scan changed (:attr:`ScanMesh.notes`)."""
    rep = {
        "scan": scan, "features": features, "template": template,
        "surface_distance": {k: result.stats[k] for k in ("mean", "median", "p95", "max")},
        "surface_distance_units": "scan units (over template vertices the scan covers)",
        "n_vertices": result.stats["n_vertices"], "n_covered": result.stats["n_covered"],
        "feature_rms": result.stats["feature_rms"],
        "flipped_fraction": result.stats["flipped_fraction"],
        "features_used": result.stats["features_used"],
        "scan_units_per_template_unit": result.stats["scan_units_per_template_unit"],
        "seconds": result.stats["seconds"],
        "prior": result.stats.get("prior"),
        "similarity": {"scale": result.similarity.scale,
                       "rotation": result.similarity.rotation.tolist(),
                       "translation": result.similarity.translation.tolist()},
        "scan_repairs": list(repairs),
        "history": list(result.history),
    }
    if credit:
        rep["credit"] = credit
    return rep


def write_fit_report(path: str | os.PathLike, result: FitResult, **kw) -> Path:
    """Write :func:`fit_report` as JSON, atomically."""
    rep = fit_report(result, **kw)
    return write_text_atomic(path, json.dumps(rep, indent=1, default=float) + "\n")


def _front_frame(result: FitResult) -> np.ndarray:
    """Fitted vertices rotated back into the template's frame (front view = template x, y)."""
    sim: Similarity = result.similarity
    return sim.inverse().apply(result.vertices)


def plot_fit(path: str | os.PathLike, result: FitResult, *, title: str = "",
             credit: str | None = None, vmax: float | None = None) -> Path:
    """Front view of the fit (template frame) coloured by distance to the scan; PNG, atomic.

    Vertices the scan does not cover are drawn grey.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.tri import Triangulation

    v = _front_frame(result)
    f = result.faces
    from .meshops import face_normals

    fn, _ = face_normals(v, f)
    front = f[fn[:, 2] > 0.0]
    d = result.distance
    vmax = float(np.percentile(d[result.covered], 99)) if vmax is None and result.covered.any() \
        else (vmax or float(d.max()))
    fig, ax = plt.subplots(figsize=(6, 7))
    order = np.argsort(v[front].mean(axis=1)[:, 2])  # far triangles first
    tri = Triangulation(v[:, 0], v[:, 1], front[order])
    covered_face = result.covered[front[order]].all(axis=1)
    ax.tripcolor(tri, facecolors=np.full(len(front), 0.7), cmap="gray", vmin=0, vmax=1)
    tri_c = Triangulation(v[:, 0], v[:, 1], front[order][covered_face])
    tp = ax.tripcolor(tri_c, d, cmap="viridis", vmin=0, vmax=vmax, shading="gouraud")
    cb = fig.colorbar(tp, ax=ax, shrink=0.8)
    cb.set_label("distance to scan (scan units)")
    s = result.stats
    ax.set_title(title or "template fit", fontsize=10)
    prior = (s.get("prior") or {}).get("name", "none (generic template)")
    ax.text(0.02, 0.02, f"mean {s['mean']:.3g}, median {s['median']:.3g}, p95 {s['p95']:.3g}\n"
            f"shape prior: {prior}", transform=ax.transAxes, fontsize=8)
    if credit:
        fig.text(0.01, 0.005, credit, fontsize=7)
    ax.set_aspect("equal")
    ax.axis("off")
    save_figure(fig, path, dpi=100, bbox_inches="tight")
    return Path(path)
