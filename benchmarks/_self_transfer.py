"""Self-transfer, a truth without a judge, for A/B measures of the rewrite (issue 13).

Rewritten with its own track as the new performance, a target clip must come back as it
was: every region the rewrite textures from another frame (the eye region's open-eyed frame,
the jaw region's closed-mouth frame) is then judged against the frame itself. The three target
clips of ``bench_transfer_judge.py`` (the 150 frames of their cached tracks in
``OUT/judge_pairs/``) are rewritten under two variants (context managers that switch a rule
off or on); on the pixels where the variants' results differ (by more than :data:`CHANGED`
levels in a channel), the mean absolute error of each against the target frame (RGB
levels), and each whole frame's PSNR. Used by ``bench_eye_rim.py``,
``bench_frame_rule.py``, ``bench_gain_support.py`` and ``bench_region_views.py``
(:func:`switch_main`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import time
from pathlib import Path

import numpy as np

from bench_transfer_judge import PAIRS, _track  # noqa: F401 (benchmarks/ is on sys.path)

#: A pixel counts as changed by a rule beyond this many levels in a channel.
CHANGED = 2


@contextlib.contextmanager
def patched(module: str, name: str, value):
    """``module.name`` set to ``value`` while the context lasts: a variant that switches a
    rule off (the module's constant, or the function it calls)."""
    mod = importlib.import_module(module)
    original = getattr(mod, name)
    setattr(mod, name, value)
    try:
        yield
    finally:
        setattr(mod, name, original)


def self_transfer(frames, track, model) -> list[np.ndarray]:
    """The target's frames rewritten with its own performance (default options)."""
    from facetransfer.rewrite_clip import RenderRun, rewrite_frames

    return [r.image for r in rewrite_frames(frames, track, track, model,
                                            run=RenderRun(workers=1, processes=False))]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def measure(clip: str, model, cache: Path, data: Path, out: Path, variants: dict,
            stem: str) -> dict:
    """Both ``variants`` (name -> context manager factory, the rule's absence first) on
    ``clip``: frames changed, pixels changed a frame, the error there and the frames' median
    PSNR per variant; ``OUT/{stem}_{clip}.png`` shows the frame where they differ most."""
    from facetransfer.io.video import iter_frames
    from facetransfer.track.result import Track

    track = Track.load(_track(clip, model, cache, data))
    frames = [f for f, _ in zip(iter_frames(data / f"{clip}.mp4"), range(track.n_frames))]
    t = time.perf_counter()
    results = {}
    for name, variant in variants.items():
        with variant():
            results[name] = self_transfer(frames, track, model)
    seconds = time.perf_counter() - t
    (na, a_), (nb, b_) = results.items()
    err = {na: [], nb: []}
    psnrs = {na: [], nb: []}
    changed = []
    for f, a, b in zip(frames, a_, b_):
        m = np.abs(b.astype(np.int16) - a).max(axis=-1) > CHANGED
        changed.append(int(m.sum()))
        for name, r in ((na, a), (nb, b)):
            if m.any():
                err[name].append(np.abs(r[m].astype(np.float64) - f[m]).mean())
            psnrs[name].append(psnr(r, f))
    k = int(np.argmax(changed))
    picture(f"{clip} frame {k}: target | {na} | {nb}", [frames[k], a_[k], b_[k]],
            out / f"{stem}_{clip}.png")
    return {"frames": len(frames), "seconds": seconds,
            "changed_pixels_mean": float(np.mean(changed)),
            "frames_changed": int(np.count_nonzero(changed)), "most_changed_frame": k,
            "mae_changed": {n: float(np.mean(e)) if e else 0.0 for n, e in err.items()},
            "psnr_frame_median": {n: float(np.median(p)) for n, p in psnrs.items()}}


def picture(title: str, images: list, path: Path) -> None:
    """The images side by side with ``title`` written over them."""
    import cv2

    from facetransfer.io.atomic import atomic_path

    row = np.concatenate(images, axis=1)
    cv2.putText(row, title, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 2)
    with atomic_path(path, overwrite=True) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(row, cv2.COLOR_RGB2BGR))


def plot(res: dict, names: tuple[str, str], title: str, path: Path) -> None:
    """Bars per clip: the error on the changed pixels of each variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    clips = list(res)
    x = np.arange(len(clips))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for j, (v, c) in enumerate(zip(names, ("#fc9272", "#3182bd"))):
        ax.bar(x - 0.2 + 0.4 * j, [res[c_]["mae_changed"][v] for c_ in clips], 0.4, color=c,
               label=v)
    ax.set_xticks(x, clips)
    ax.set_ylabel("mean |result - target| (levels)")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def run(out: Path, variants: dict, stem: str, title: str) -> dict:
    """:func:`measure` on every target clip of the judge's pairs, printed, written to
    ``OUT/{stem}.json`` and plotted in ``OUT/{stem}.png``."""
    import json

    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    (out / "judge_pairs").mkdir(parents=True, exist_ok=True)
    data = Path(data_dir()) / "video"
    model = load_default_model()
    na, nb = variants
    res = {}
    for _, clip in PAIRS.values():
        res[clip] = r = measure(clip, model, out / "judge_pairs", data, out, variants, stem)
        print(f"{clip}: {r['frames_changed']}/{r['frames']} frames changed, "
              f"{r['changed_pixels_mean']:.0f} px a frame; error there {na} "
              f"{r['mae_changed'][na]:.2f} -> {nb} {r['mae_changed'][nb]:.2f}; "
              f"PSNR {r['psnr_frame_median'][na]:.2f} -> "
              f"{r['psnr_frame_median'][nb]:.2f} dB", flush=True)
    with atomic_path(out / f"{stem}.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(res, indent=2))
    plot(res, (na, nb), title, out / f"{stem}.png")
    return res


def switch_main(doc: str, off: str, module: str, name: str, value, on: str, stem: str,
                title: str) -> int:
    """:func:`main` of a benchmark script that compares a rule switched off (``module.name``
    set to ``value``, the variant ``off``) with the code as it is (the variant ``on``)."""
    return main(doc, {off: lambda: patched(module, name, value), on: contextlib.nullcontext},
                stem, title)


def main(doc: str, variants: dict, stem: str, title: str, argv=None) -> int:
    """A benchmark script's command line: ``--out`` (default ``out/benchmarks``), then
    :func:`run`."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    args = ap.parse_args(argv)
    run(Path(args.out), variants, stem, title)
    return 0
