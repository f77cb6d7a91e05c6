"""``facetransfer demo``: the main job end to end on the default inputs (what ``make demo`` runs).

1. the default model (:mod:`facetransfer.default_model`: ``ict-arkit``, the ARKit blendshapes on
   ICT-FaceKit identities), built once and cached in the user cache;
2. two clips of the data folder (``$FACETRANSFER_DATA_DIR/video``): ``driving_d6.mp4`` gives the
   expressions, ``WDA_KatieHill_000.mp4`` is the target footage (without a data folder, two
   synthetic clips of :mod:`facetransfer.synth` stand in);
3. both are tracked (§5; a landmark-only fit if the optical-flow tracker fails), the source's
   expressions are put on the target's identity and pose (§6, Fig. 7C) and rendered back into
   the target footage (:mod:`facetransfer.video_transfer`, :mod:`facetransfer.rewrite`);
4. ``OUT/demo.mp4`` (source | target | result side by side, with the target's audio; H.264 by
   default, :mod:`facetransfer.io.video`),
   ``OUT/demo.png`` (a contact sheet of six frames) and ``OUT/demo_track.npz`` (the new
   performance) are written, each atomically.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import AssetError, VideoError
from .texture.face import resolve_mouth_mode
from .rewrite_options import RewriteOptions
from .transfer_plan import plan_transfer
from .video_transfer import RenderTarget, render_plan

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_SOURCE", "DEFAULT_TARGET", "DemoResult", "ensure_default_model", "default_inputs", "synthetic_inputs", "side_by_side",
           "contact_sheet", "run_demo"]

DEFAULT_SOURCE = "driving_d6.mp4"  # strong expressions: the mouth opens and closes
DEFAULT_TARGET = "WDA_KatieHill_000.mp4"


def ensure_default_model(*, progress_factory=None):
    """The default model (:func:`facetransfer.default_model.load_default_model`), built and
    cached on first use with a progress bar from ``progress_factory(desc, total)``.

    Returns
    -------
    MultilinearModel
    """
    from .default_model import DEFAULT_DATASET, load_default_model

    bar = None

    def cb(done, total):
        nonlocal bar
        if progress_factory is None:
            return
        if bar is None:
            bar = progress_factory(f"dataset {DEFAULT_DATASET}", total)
        bar.total = total
        bar.update(done - bar.n)

    try:
        return load_default_model(progress=cb, announce=log.info)
    finally:
        if bar is not None:
            bar.close()


def default_inputs() -> tuple[Path, Path]:
    """``(source, target)`` videos of the data folder."""
    from .assets import data_dir

    root = data_dir()
    if root is None:
        raise AssetError("the demo clips live in the data folder: set FACETRANSFER_DATA_DIR to "
                         "the offline mirror (it has video/driving_d6.mp4 and "
                         "video/WDA_KatieHill_000.mp4)")
    src, tgt = Path(root) / "video" / DEFAULT_SOURCE, Path(root) / "video" / DEFAULT_TARGET
    for p in (src, tgt):
        if not p.is_file():
            raise AssetError(f"demo clip {p} is missing from the data folder {root}")
    return src, tgt


def synthetic_inputs(folder, model, *, n_frames: int = 120, size: int = 512
                     ) -> tuple[Path, Path, Path, Path]:
    """Two synthetic clips (:mod:`facetransfer.synth`) for when the data folder is missing:
    ``source.mp4`` (lively expressions) and ``target.mp4`` (another identity, calmer), and
    their true tracks ``source.npz``, ``target.npz`` (no face detector needed).

    Returns
    -------
    (source video, target video, source track, target track)
    """
    import numpy as np

    from .io.video import write_video
    from .synth import make_clip, random_performance
    from .track import Track

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    labels = model.labels[0]
    paths = []
    for name, ident, seed, every in (("source", labels[1 % len(labels)], 3, 0.6),
                                     ("target", labels[-1], 8, 2.0)):
        perf = random_performance(model, n_frames, seed=seed, size=(size, size), identity=ident,
                                  key_every=every)
        clip = make_clip(model, perf, seed=seed)
        p = d / f"{name}.mp4"
        write_video(p, clip.frames, perf.fps)
        t = clip.truth
        Track(fps=t.fps, frame_size=t.frame_size, rotation=t.rotation, scale=t.scale,
              translation=t.translation, weights=t.weights, landmarks2d=t.landmarks2d,
              confidence=np.ones(t.n_frames), lost=np.zeros(t.n_frames, bool),
              model_hash=model.content_hash, mode_names=model.mode_names,
              source=str(p)).with_source_facts().save(d / f"{name}.npz")
        paths.append(p)
    return paths[0], paths[1], d / "source.npz", d / "target.npz"


def _fit_height(img: np.ndarray, H: int, W: int) -> np.ndarray:
    """``img`` scaled to height ``H`` and padded or cropped (centred) to width ``W``."""
    import cv2

    h, w = img.shape[:2]
    nw = max(1, int(round(w * H / h)))
    r = cv2.resize(img, (nw, H), interpolation=cv2.INTER_AREA if H < h else cv2.INTER_LINEAR)
    if nw >= W:
        x0 = (nw - W) // 2
        return r[:, x0:x0 + W]
    out = np.zeros((H, W, 3), np.uint8)
    x0 = (W - nw) // 2
    out[:, x0:x0 + nw] = r
    return out


def side_by_side(source: np.ndarray, target: np.ndarray, result: np.ndarray, *,
                 labels: bool = True, source_label: str = "source (expressions)") -> np.ndarray:
    """One demo frame: source | target | result at the target's size, (H, 3 W, 3) uint8."""
    import cv2

    H, W = target.shape[:2]
    tiles = [_fit_height(source, H, W), target.copy(), result.copy()]
    if labels:
        for t, text in zip(tiles, (source_label, "target", "result")):
            cv2.putText(t, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4,
                        cv2.LINE_AA)
            cv2.putText(t, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2,
                        cv2.LINE_AA)
    W2 = W - (W % 2)
    H2 = H - (H % 2)
    return np.ascontiguousarray(np.hstack([t[:H2, :W2] for t in tiles]))


#: Characters of the tool's lines that OpenCV's Hershey font cannot draw (it draws "?" for
#: each byte of a character beyond ASCII: the sheet's "r=–" read "r=???"), drawn as these.
_DRAWN_AS = {"\u2013": "-", "\u2014": "-", "\u2212": "-", "\u00d7": "x", "\u2019": "'",
             "\u2026": "...", "\u00b2": "^2", "\u00b0": " deg"}


def drawable_caption(text: str) -> str:
    """``text`` as the contact sheet can draw it: typographic dashes, times, degrees and the
    like as ASCII, any other character beyond ASCII as "?" (one, not one per byte)."""
    text = "".join(_DRAWN_AS.get(c, c) for c in text)
    return text.encode("ascii", "replace").decode("ascii")


def contact_sheet(frames: list[np.ndarray], path, *, columns: int = 2, scale: float = 0.5,
                  overwrite: bool = True, caption: str | None = None) -> Path:
    """Write a grid of side-by-side frames to ``path`` (PNG), atomically, with an optional
    one-line caption under it."""
    import cv2
    from PIL import Image

    from .io.atomic import atomic_path

    small = [cv2.resize(f, (int(f.shape[1] * scale), int(f.shape[0] * scale)),
                        interpolation=cv2.INTER_AREA) for f in frames]
    rows = []
    for k in range(0, len(small), columns):
        row = small[k:k + columns]
        while len(row) < columns:
            row.append(np.zeros_like(small[0]))
        rows.append(np.hstack(row))
    sheet = np.vstack(rows)
    if caption:  # at 0.5 of the font's height, smaller if it would not fit the width
        caption = drawable_caption(caption)
        (w, _), _ = cv2.getTextSize(caption, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        size = min(0.5, 0.5 * (sheet.shape[1] - 16) / max(w, 1))
        band = np.full((28, sheet.shape[1], 3), 255, np.uint8)
        cv2.putText(band, caption, (8, 19), cv2.FONT_HERSHEY_SIMPLEX, size, (20, 20, 20), 1,
                    cv2.LINE_AA)
        sheet = np.vstack([sheet, band])
    with atomic_path(path, overwrite=overwrite) as tmp:
        Image.fromarray(sheet).save(tmp, format="PNG")
    return Path(path)


@dataclass(frozen=True)
class DemoResult:
    """Outputs of :func:`run_demo` and seconds per stage."""

    video: Path
    sheet: Path
    track: Path
    n_frames: int
    method: str
    timings: dict = field(default_factory=dict)
    fidelity: object = None  #: :class:`facetransfer.fidelity.Fidelity`, or None if not judged


def run_demo(out_dir, *, frames: int = 120, source=None, target=None, model=None,
             options: RewriteOptions | None = None, progress_factory=None,
             overwrite: bool = True, video_options=None, judge: bool = True) -> DemoResult:
    """Transfer the expressions of the source clip onto the target clip (§6, Fig. 7C).

    Parameters
    ----------
    out_dir : path-like
        Created if missing; receives ``demo.mp4`` (``demo.mov`` for ProRes), ``demo.png`` and
        ``demo_track.npz``.
    frames : int
        Target frames to use (the source is read for the same duration).
    source, target : path-like, optional
        Default: :func:`default_inputs`.
    model : MultilinearModel, optional
        Default: :func:`ensure_default_model`.
    options : RewriteOptions, optional
        How the clips are tracked and the face rendered (default: ``RewriteOptions()``;
        checked when made, before any work). ``track_method="auto"`` falls back to a
        landmark-only fit if tracking fails; a mouth of None is
        :func:`facetransfer.texture.face.default_mouth_mode`.
    video_options : VideoOptions, optional
        Codec and CRF of the video (:class:`facetransfer.io.video.VideoOptions`).

    Returns
    -------
    DemoResult
    """
    opts = RewriteOptions() if options is None else options
    if model is not None:  # an unusable mouth mode fails before any work
        resolve_mouth_mode(opts.mouth, model)
    made = not Path(out_dir).exists()
    try:
        return _demo(out_dir, opts, model, frames, source, target, progress_factory,
                     overwrite, video_options, judge)
    except BaseException:
        if made and Path(out_dir).is_dir() and not any(Path(out_dir).iterdir()):
            Path(out_dir).rmdir()  # a failed first run leaves no empty folder
        raise


def _demo(out_dir, opts: RewriteOptions, model, frames: int, source, target, progress_factory,
          overwrite: bool, video_options, judge: bool) -> DemoResult:
    """:func:`run_demo` once its options are checked."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    video_path, sheet_path, track_path = _demo_paths(out_dir, video_options, overwrite)
    if model is None:
        model = ensure_default_model(progress_factory=progress_factory)
    timings["model"] = time.perf_counter() - t0
    source, target, tracks = _demo_inputs(source, target, model, Path(out_dir), frames)
    plan, opts = _plan_with_fallback(target, source, model, opts, frames, tracks,
                                     progress_factory)
    sheet = _DemoFrames(plan, judge, _take_panels(source, plan, model))
    output = RenderTarget(video_path, target, video_options, overwrite)
    rendered = render_plan(plan, model, output, options=opts, progress_factory=progress_factory,
                           compose=sheet.compose)
    timings.update(rendered.timings)
    fid = _judge(sheet.panels, plan.fps, _aspects(plan)) if judge else None
    timings["judge"] = time.perf_counter() - t0 - sum(timings.values())
    contact_sheet(sheet.sheet_frames, sheet_path, overwrite=overwrite,
                  caption=None if fid is None else fid.line())
    plan.new_track.save(track_path, overwrite=overwrite)
    timings["total"] = time.perf_counter() - t0
    return DemoResult(video_path, sheet_path, track_path, plan.n_frames, opts.track_method,
                      timings, fid)


def _demo_paths(out_dir, video_options, overwrite: bool) -> tuple[Path, Path, Path]:
    """``(video, sheet, track)`` in ``out_dir`` (created), each checked for writing."""
    from .io.atomic import check_output_path
    from .io.video import VideoOptions, check_video_output

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ext = ".mov" if (video_options or VideoOptions()).codec == "prores" else ".mp4"
    video_path, sheet_path, track_path = (out / f"demo{ext}", out / "demo.png",
                                          out / "demo_track.npz")
    check_video_output(video_path, video_options, overwrite=overwrite)
    for p in (sheet_path, track_path):
        check_output_path(p, overwrite=overwrite)
    return video_path, sheet_path, track_path


def _demo_inputs(source, target, model, out: Path, frames: int):
    """``(source, target, track files)``: the given clips, else the data folder's, else two
    synthetic clips with their true tracks (``{"expression_track": ..., "target_track": ...}``)."""
    tracks: dict = {}
    if source is None or target is None:
        try:
            s, t = default_inputs()
        except AssetError as exc:  # no data folder: degrade to synthetic footage
            log.warning("%s; using synthetic clips (with their true tracks) instead", exc)
            s, t, ts, tt = synthetic_inputs(out / "inputs", model, n_frames=frames)
            tracks = {"expression_track": ts, "target_track": tt}
        source = s if source is None else source
        target = t if target is None else target
    return source, target, tracks


def _plan_with_fallback(target, source, model, opts: RewriteOptions, frames: int, tracks: dict,
                        progress_factory):
    """``(plan, options)``: :func:`facetransfer.transfer_plan.plan_transfer` with the chosen
    tracker; with ``"auto"``, a landmark-only fit when tracking fails (the demo degrades
    instead of failing)."""
    def plan(method):
        return plan_transfer(target, model, expression_from=source, max_frames=frames,
                             track_method=method, speed=opts.speed,
                             progress_factory=progress_factory, **tracks)

    try:
        return plan(opts.track_method), opts
    except (KeyboardInterrupt, MemoryError, VideoError):
        raise       # a clip without a face, or one that cannot be read: no fit would help
    except Exception as exc:  # noqa: BLE001 - the demo degrades instead of failing
        if opts.track_method != "auto":
            raise
        log.warning("tracking failed (%s: %s); falling back to a landmark-only fit",
                    type(exc).__name__, exc)
        opts = opts.with_(track_method="landmarks")
        return plan(opts.track_method), opts


def _take_panels(source, plan, model):
    """For a Live Link Face take as the source (it has no pictures; the plan's mouth frames
    are the target's own): the take's performance on the model's mean face, in the target's
    pose and frame (:func:`facetransfer.puppet_video.puppet_frames` of the new track), the
    source panel that the judge compares the result with; None for a video source."""
    from .take import is_take

    if not is_take(source):
        return None
    from .puppet_video import puppet_frames

    return puppet_frames(plan.new_track, model, model.weight_mean("identity"),
                         size=tuple(plan.target_frames.shape[2:0:-1]))


class _DemoFrames:
    """The demo's frame composer (source | target | result): keeps six frames for the contact
    sheet and, for the judge, the three panels at half size. ``take``: the source panels of a
    take (:func:`_take_panels`, one per frame in order), else the plan's mouth frames."""

    def __init__(self, plan, judge: bool, take=None) -> None:
        n = plan.n_frames
        self.plan, self.judge, self.take = plan, judge, take
        self.pick = set(np.linspace(0, n - 1, 6).round().astype(int).tolist())
        self.sheet_frames: list[np.ndarray] = []
        self.panels: list[list[np.ndarray]] = [[], [], []]

    def compose(self, i: int, r) -> np.ndarray:
        plan = self.plan
        source = plan.mouth_frames[plan.mouth_index[i]] if self.take is None else \
            next(self.take)
        trio = (source, plan.target_frames[i], r.image)
        frame = side_by_side(*trio, source_label="source (expressions)" if self.take is None
                             else "source (the take on the model)")
        if i in self.pick:
            self.sheet_frames.append(frame)
        if self.judge:
            for k, f in enumerate(trio):
                self.panels[k].append(f[::2, ::2].copy())
        return frame


def _aspects(plan) -> tuple[float, float, float]:
    """The pixel aspects of the source, target and result panels (their tracks')."""
    a = plan.target_track.pixel_aspect
    return (a if plan.mouth_track is None else plan.mouth_track.pixel_aspect), a, a


def _judge(panels, fps, aspects=(1.0, 1.0, 1.0)):
    """The independent judge on the three panels (:mod:`facetransfer.fidelity`), or None if
    MediaPipe is unavailable."""
    from .errors import FaceTransferError
    from .fidelity import judge_frames

    try:
        return judge_frames(*panels, fps=fps, aspects=aspects)
    except (FaceTransferError, ImportError) as exc:
        log.warning("no fidelity figures: %s", exc)
        return None
