"""``facetransfer impute eval``: measure missing-data imputation (Vlasic et al. 2005, §4.4).

Hides a fraction of the cells of a data set at random (never a whole slice), predicts them with
every method of :mod:`facetransfer.impute`, and writes ``DIR/report.json``,
``DIR/error_vs_missing.png`` and ``DIR/fig4.png`` (the paper's Fig. 4: our prediction, the true
face, the averaging prediction).
"""

from __future__ import annotations

import json
import logging
import platform
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

DEFAULT_FRACTIONS = "0.1,0.2,0.3,0.4,0.5"
DEFAULT_METHODS = "ppca,average,naive,tensorly"
#: Bytes an evaluation keeps for each run (one method at one fraction in one trial): its
#: error, relative error and seconds, in the records and again in the JSON report (about 390
#: at the peak, measured; rounded up). What bounds ``--trials``: runs x this <= the memory
#: available (before: at most 1000 trials, whatever the fractions and methods).
RUN_BYTES = 512


def register(sub) -> None:
    """Add ``impute eval`` to the facetransfer parser."""
    from .common import add_command_group, integer_from

    isub = add_command_group(sub, "impute", dest="impute_command",
                             help="missing-data imputation (§4.4)",
                             description="Fill missing cells of incomplete face data sets "
                             "(§4.4).")
    e = isub.add_parser("eval", help="hold out random cells and measure every imputation method",
                        description="Hide a fraction of the cells at random (never a whole slice), "
                        "predict them with every method and write DIR/report.json, "
                        "DIR/error_vs_missing.png and DIR/fig4.png.")
    e.add_argument("--dataset", required=True,
                   help="ict-trilinear, ict-bilinear, a manifest .csv or a FaceWarehouse folder")
    e.add_argument("--missing", default=DEFAULT_FRACTIONS,
                   help=f"comma-separated fractions of cells to hide (default {DEFAULT_FRACTIONS})")
    e.add_argument("--trials", type=int, default=5,
                   help="random trials per fraction (default 5); the runs are trials x fractions "
                   "x methods, each from under a second (average) to tens of seconds (ppca, "
                   "naive, tensorly on ict-trilinear), and each keeps ~0.5 kB of results: the "
                   "most trials are those whose runs fit in the memory available")
    e.add_argument("--seed", type=integer_from(0), default=0,
                   help="seed of the held-out cells (default 0)")
    e.add_argument("--methods", default=DEFAULT_METHODS,
                   help=f"comma-separated methods (default {DEFAULT_METHODS}); also "
                   "ppca-mouth (§4.4's mouth emphasis: own covariances for the mouth region) and "
                   "ppca-regions8 (8 soft face regions)")
    e.add_argument("--out", required=True, help="output folder (created if needed)")
    e.add_argument("--no-figures", action="store_true", help="write report.json only")
    e.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier run in DIR")
    e.set_defaults(func=_eval)


def _floats(text: str, what: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"{what} must be comma-separated numbers, got {text!r}") from None
    if not vals:
        raise ValueError(f"{what} is empty")
    return vals


def _eval_inputs(args) -> tuple[list[float], list[str], Path]:
    """``impute eval``'s fractions, methods and output folder, checked before any work: an
    earlier run's results in the folder are replaced only with ``--overwrite``."""
    from ..impute import EVAL_VARIANTS, METHODS
    from ..impute.evaluate import check_no_repeats
    from ..io.atomic import check_output_path

    fractions = _floats(args.missing, "--missing")
    for f in fractions:
        if not 0 < f < 1:
            raise ValueError(f"--missing fractions must be in (0, 1), got {f}")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for m in methods:
        if m not in METHODS and m not in EVAL_VARIANTS:
            raise ValueError(f"--methods: unknown method {m!r}; choose from "
                             f"{', '.join(METHODS + tuple(EVAL_VARIANTS))}")
    if not methods:
        raise ValueError("--methods is empty")
    check_no_repeats(fractions, "--missing")
    check_no_repeats(methods, "--methods")
    if args.trials < 1:
        raise ValueError(f"--trials must be at least 1, got {args.trials}")
    _check_trials_fit(args.trials, len(fractions) * len(methods))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    names = ("report.json",) + (() if args.no_figures else ("error_vs_missing.png", "fig4.png"))
    for name in names if out.is_dir() else ():     # a new folder is made after the work
        check_output_path(out / name, overwrite=args.overwrite)
    return fractions, methods, out


def _check_trials_fit(trials: int, per_trial: int) -> None:
    """ValueError unless ``trials`` x ``per_trial`` runs' results (:data:`RUN_BYTES` each) fit
    in the memory available (before: at most 1000 trials; ``10**30`` ran on until
    interrupted)."""
    from ..io.memory import available_memory

    have = available_memory()
    if trials * per_trial * RUN_BYTES > have:
        most = max(have // (per_trial * RUN_BYTES), 1)
        raise ValueError(
            f"--trials {trials}: {trials * per_trial} runs (trials x fractions x methods) "
            f"keep ~{RUN_BYTES} bytes of results each, more than the {have / 2**30:.1f} GiB "
            f"available; give --trials {most} or fewer")


def _eval(args) -> int:
    from tqdm import tqdm

    from ..datasets import load_dataset
    from ..impute import evaluate_imputation
    from .common import progress_disabled

    fractions, methods, out = _eval_inputs(args)
    with tqdm(desc="loading data set", unit="mesh", leave=False,
              disable=progress_disabled()) as lbar:
        def loaded(done: int, total: int) -> None:
            lbar.total = total
            lbar.n = done
            lbar.refresh()

        ds = load_dataset(args.dataset, progress=loaded)
    total = len(fractions) * args.trials * len(methods)
    bar = tqdm(total=total, desc="impute eval", unit="run", leave=False,
               disable=progress_disabled())

    def progress(msg: str) -> None:
        bar.update(1)
        bar.set_postfix_str(msg[:60])
        log.info(msg)

    t0 = time.perf_counter()
    try:
        ev = evaluate_imputation(ds, fractions, trials=args.trials, seed=args.seed,
                                 methods=methods, progress=progress)
    finally:
        bar.close()
    out.mkdir(parents=True, exist_ok=True)
    report = make_report(ev, ds, dataset=str(args.dataset), seed=args.seed, trials=args.trials,
                         seconds=time.perf_counter() - t0)
    written = [write_report(out / "report.json", report)]
    if not args.no_figures:
        written.append(plot_error_vs_missing(ev, out / "error_vs_missing.png",
                                             title=str(args.dataset)))
        if ev.examples:
            written.append(plot_fig4(ev.examples, ds.faces, out / "fig4.png"))
    for r in ev.results:
        print(f"{r.method:9s} missing {r.missing:.2f}: error {100 * r.error_mean:6.2f} % "
              f"(max {100 * r.error_max:6.2f} %), relative {100 * r.relative_error_mean:6.1f} %, "
              f"{r.seconds:6.2f} s")
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def make_report(ev, ds, **meta) -> dict:
    """The JSON report of an :class:`~facetransfer.impute.ImputeEvaluation`."""
    return {
        "dataset": meta.get("dataset"),
        "cells": list(ds.shape),
        "mode_names": list(ds.mode_names),
        "n_vertices": ds.n_vertices,
        "seed": meta.get("seed"),
        "trials": meta.get("trials"),
        "seconds_total": meta.get("seconds"),
        "error_definition": "Frobenius norm of the error over the held-out cells / Frobenius norm "
                            "of the whole data set (Vlasic et al. 2005, §4.4)",
        "relative_error_definition": "Frobenius norm of the error over the held-out cells / "
                                     "Frobenius norm of the held-out cells' displacement from "
                                     "their identity's neutral cell",
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
        "results": [{"method": r.method, "missing": r.missing, "error_mean": r.error_mean,
                     "error_max": r.error_max, "relative_error_mean": r.relative_error_mean,
                     "seconds": r.seconds, "errors": list(r.errors),
                     "relative_errors": list(r.relative_errors)} for r in ev.results],
    }


def write_report(path: Path, report: dict) -> Path:
    from ..io.atomic import write_text_atomic
    from ..model import json_default

    return write_text_atomic(path, json.dumps(report, indent=2, default=json_default) + "\n")


def plot_error_vs_missing(ev, path: Path, *, title: str = "") -> Path:
    """Two panels: the paper's error and the relative error vs the missing fraction, per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.atomic import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    methods = list(dict.fromkeys(r.method for r in ev.results))
    for m in methods:
        rs = sorted((r for r in ev.results if r.method == m), key=lambda r: r.missing)
        x = [100 * r.missing for r in rs]
        axes[0].plot(x, [100 * r.error_mean for r in rs], "o-", label=m)
        axes[1].plot(x, [100 * r.relative_error_mean for r in rs], "o-", label=m)
    axes[0].axhline(9.0, color="gray", ls="--", lw=1, label="paper: 9 %")
    axes[0].set_ylabel("error / ||data|| (%)")
    axes[1].set_ylabel("error / ||held-out displacement|| (%)")
    for ax in axes:
        ax.set_xlabel("missing cells (%)")
        ax.grid(alpha=0.3)
        ax.set_yscale("log")
        ax.legend()
    fig.suptitle(f"Imputation of held-out faces (§4.4) {title}")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path


def _render_face(vertices: np.ndarray, faces: np.ndarray, size: int, camera=None) -> np.ndarray:
    """A Lambert-shaded front view (H, W, 3) uint8; matplotlib fallback without the renderer."""
    try:
        from ..render import look_at_weak_perspective, render
    except ImportError:  # pragma: no cover - the renderer is part of the package
        render = None
    if render is not None:
        cam = camera if camera is not None else look_at_weak_perspective(vertices, (size, size))
        return render(vertices, faces, cam, (size, size), colors=np.full((len(vertices), 3), 0.8),
                      background=(255, 255, 255)).image
    import matplotlib.pyplot as plt  # pragma: no cover

    fig = plt.figure(figsize=(2, 2), dpi=size / 2)
    ax = fig.add_axes([0, 0, 1, 1])
    n = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                 vertices[faces[:, 2]] - vertices[faces[:, 0]])
    shade = np.abs(n[:, 2]) / np.maximum(np.linalg.norm(n, axis=1), 1e-12)
    ax.tripcolor(vertices[:, 0], vertices[:, 1], faces, facecolors=shade, cmap="gray")
    ax.set_aspect("equal")
    ax.axis("off")
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return img


def plot_fig4(examples: dict, faces: np.ndarray, path: Path, *, size: int = 220) -> Path:
    """The paper's Fig. 4: rows = our prediction (ppca), the true face, the averaging prediction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.atomic import save_figure

    rows = [(m, lab) for m, lab in (("ppca", "ours (PPCA, §4.4)"), ("truth", "actual face"),
                                    ("average", "averaging")) if m in examples]
    n_ex = len(examples["cells"])
    fig, axes = plt.subplots(len(rows), n_ex, figsize=(2.2 * n_ex, 2.3 * len(rows)), squeeze=False)
    for c in range(n_ex):
        cam = None
        try:
            from ..render import look_at_weak_perspective

            cam = look_at_weak_perspective(examples["truth"][c], (size, size))
        except ImportError:  # pragma: no cover
            pass
        for r, (m, lab) in enumerate(rows):
            V = examples[m][c]
            err = "" if m == "truth" else (
                f"\nerror {np.linalg.norm(V - examples['truth'][c]):.3g} (data units)")
            axes[r, c].imshow(_render_face(V, faces, size, cam))
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
            name = examples["labels"][c] if "labels" in examples else str(examples["cells"][c])
            axes[r, c].set_title(f"{name}{err}", fontsize=7)
            if c == 0:
                axes[r, c].set_ylabel(lab)
    fig.suptitle(f"Held-out faces ({100 * examples['missing']:.0f} % missing): ours, truth, "
                 f"averaging (cf. Fig. 4)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    return path
