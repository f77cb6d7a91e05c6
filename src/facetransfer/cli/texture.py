"""``facetransfer texture ...``: default face texture, texture lifting from video, Poisson blending (§6).

    facetransfer texture default --model MODEL.npz --out tex.png [--size 512] [--seed 0] \\
        [--source procedural|lee-perry-smith|auto]
    facetransfer texture lift CLIP.mp4 --track CLIP.truth.npz --model MODEL.npz --out tex.png \\
        [--size 512] [--step 2] [--function tf.npz]
    facetransfer texture blend --source face.png --target frame.png --mask mask.png --out out.png \\
        [--method auto|opencv|solver] [--mixed] [--feather 3]

``--track`` takes a tracker output (``TRACK.npz``) or the ground truth of ``synth-video``
(``CLIP.truth.npz``): both carry the per-frame pose and model weights.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError
from ..io.atomic import check_output_path, write_image
from .common import (add_command_group, default_model_for, frame_count, integer_from,
                     option_with, progress_disabled, resolve_model)

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _image_out(path: str, args=None, inputs=()) -> Path:
    out = check_output_path(path, overwrite=getattr(args, "overwrite", False), inputs=inputs)
    if out.suffix.lower() not in _IMAGE_SUFFIXES:
        raise FaceTransferError(f"--out {out}: expected a .png or .jpg image")
    return out


def _read_image(path: str, what: str, *, gray: bool = False, deep: bool = False) -> np.ndarray:
    """An RGB image ``(H, W, 3) uint8`` (or grey ``(H, W)``); one clear error if unreadable.
    ``deep``: a 16-bit file's RGB stays ``uint16``. An 8-bit RGBA TIFF of straight alpha: its
    colour as stored (OpenCV's reader premultiplies it: a blend worked on darkened colour)."""
    import cv2

    from ..io.frame_file import read_image, straight_tiff_rgb
    from ..io.npz import check_input_file

    p = check_input_file(path, what)
    stored = None if gray else straight_tiff_rgb(Path(p))
    if stored is not None:
        return stored
    img = read_image(Path(p), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH) if deep else None
    if img is None or img.dtype not in (np.uint8, np.uint16):   # e.g. a float TIFF: 8 bits
        img = read_image(Path(p), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR)
    if img is None:
        raise FaceTransferError(f"{what} {p} is not an image OpenCV can read")
    return img if gray else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _read_mask(path: str, shape: tuple[int, int]) -> np.ndarray:
    p = Path(path)
    m = _read_image(path, "mask", gray=True)
    if m.shape != shape:
        raise FaceTransferError(f"mask {p} is {m.shape[1]}x{m.shape[0]}, the target is "
                                f"{shape[1]}x{shape[0]}")
    if not (m > 127).any():
        top = int(m.max(initial=0))
        raise FaceTransferError(f"mask {p} has no white pixel (above 127; its brightest is "
                                f"{top}): nothing to paste"
                                + (" (a mask of 0 and 1? white is 255)" if top == 1 else ""))
    return m > 127


def _load_track(path: str):
    """A tracker ``TRACK.npz`` or a ``synth-video`` ``CLIP.truth.npz``."""
    p = Path(path)
    try:  # only the names of the arrays: the loader below reads (and checks) the file
        with np.load(p, allow_pickle=False) as z:
            is_truth = "meta" in z.files
    except Exception:
        is_truth = False  # Track.load names what is wrong with it
    if is_truth:
        from ..synth import load_truth

        return load_truth(p)
    from ..track.result import Track

    return Track.load(p)


def _lift_model(track, model_path):
    """``--model``, else the default model for a track made with it (else an error asking for
    ``--model``); synth-video's truth takes the default model and checks it itself, naming its
    file and the model that rendered it (before: an AttributeError's traceback)."""
    from ..synth import SyntheticTruth

    if model_path is not None or isinstance(track, SyntheticTruth):
        return resolve_model(model_path)
    return default_model_for(track)


def cmd_default(args: argparse.Namespace) -> int:
    from ..texture import LEE_PERRY_SMITH_CREDIT, default_face_texture

    out = _image_out(args.out, args, [args.model])
    if not 8 <= args.size <= 8192:
        raise FaceTransferError(f"--size must be in 8..8192, got {args.size}")
    model = resolve_model(args.model)
    procedural = default_face_texture(model, size=args.size, seed=args.seed)
    tex = procedural if args.source == "procedural" else \
        default_face_texture(model, size=args.size, seed=args.seed, source=args.source)
    write_image(out, tex, overwrite=args.overwrite)
    if args.source != "procedural" and not np.array_equal(tex, procedural):
        print(f"wrote {out} ({args.size}x{args.size}, Lee Perry-Smith scan on the model's UVs; "
              f"credit: {LEE_PERRY_SMITH_CREDIT})")
    else:
        print(f"wrote {out} ({args.size}x{args.size} procedural skin texture)")
    return 0


def cmd_lift(args: argparse.Namespace) -> int:
    import itertools

    from tqdm import tqdm

    from ..io.video import grown_size_of, iter_frames, video_info
    from ..texture import (TextureFunction, lift_merged, lift_track, merge_textures,
                           texture_to_uint8)

    args.k = option_with(args.k, 4, "--k", args.function, "--function")
    inputs = [args.video, args.track, args.model]
    out = _image_out(args.out, args, inputs)
    if args.function and Path(args.function).resolve() == Path(out).resolve():
        raise FaceTransferError(f"--function {args.function} is --out's file: give the texture "
                                "function a name of its own (.npz)")
    fn_out = check_output_path(args.function, overwrite=args.overwrite, inputs=inputs + [out]) \
        if args.function else None
    if fn_out is not None and fn_out.suffix.lower() != ".npz":
        raise FaceTransferError(f"--function {fn_out}: expected an .npz file")
    if args.step < 1:
        raise FaceTransferError(f"--step must be >= 1, got {args.step}")
    if not 8 <= args.size <= 4096:
        raise FaceTransferError(f"--size must be in 8..4096, got {args.size}")
    if args.k < 1:
        raise FaceTransferError(f"--k must be >= 1 (neighbours of the texture function), "
                                f"got {args.k}")
    info = video_info(args.video)       # a file or an image sequence, checked
    track = _load_track(args.track)
    model = _lift_model(track, args.model)
    track.check_model(model)
    w, h = (int(v) for v in track.frame_size)
    grown = grown_size_of(info.size, (w, h))   # an odd-sized synth-video clip, 4:2:0
    if tuple(track.frame_size) != tuple(info.size) and not grown:
        raise FaceTransferError(f"track {args.track} is for {track.frame_size[0]}x"
                                f"{track.frame_size[1]} frames, the video is "
                                f"{info.size[0]}x{info.size[1]}")
    if hasattr(track, "warn_other_video"):    # a tracker's track (a truth file names none)
        track.warn_other_video(args.video, "the texture is lifted through another face's "
                               "motion")
    _warn_performance(track, args.track)
    n = int(track.scale.shape[0])
    used = (n + args.step - 1) // args.step
    if fn_out is not None:
        _check_function_memory(used, args.size, args.step)
    with tqdm(total=used, desc="texture lift", unit="frame",
              disable=progress_disabled()) as bar:
        # a track of the clip's first n frames (``track --max-frames``) lifts those
        frames = itertools.islice(iter_frames(args.video), n)
        if grown:                     # the frames as they were, without the repeated edge
            frames = (f[:h, :w] for f in frames)
        if fn_out is None:            # merged as they come: one texture's memory
            merged, used = lift_merged(model, frames, track, tex_size=args.size,
                                       step=args.step, progress=bar.update)
        else:                         # the texture function holds every frame's
            lt = lift_track(model, frames, track, tex_size=args.size, step=args.step,
                            progress=bar.update)
            merged = merge_textures(lt.lifted)
    write_image(out, texture_to_uint8(merged.texture), overwrite=args.overwrite)
    seen = float((merged.weight > 1e-6).mean())
    msg = f"wrote {out} (merged from {frame_count(used)}, {100 * seen:.0f}% of texels seen)"
    if fn_out is not None:
        TextureFunction.from_lifted(lt.lifted, lt.attributes, k=args.k).save(
            fn_out, overwrite=args.overwrite)
        msg += f" and {fn_out} (texture function, k={args.k})"
    print(msg)
    return 0


def _warn_performance(track, path) -> None:
    """A warning where the track file ``path`` is a performance a transfer made
    (:attr:`facetransfer.track.Track.made_by`, ``transfer --save-track``): its meshes are what
    the transfer drew into its output, not the face of the clip it names (the target), so the
    target's frames lifted through it put its skin on expressions it does not make."""
    made = getattr(track, "made_by", "")
    if made:
        logging.getLogger(__name__).warning(
            "track %s is a performance made by %s (--save-track), not a track of %s: lifted "
            "from that clip the texture follows expressions its face does not make (lift the "
            "transfer's output video through it, or give the clip's own track)", path, made,
            Path(str(track.source)).name if track.source else "the clip it names")


def _check_function_memory(used: int, size: int, step: int) -> None:
    """Refuse a ``--function`` whose frames' textures would not fit in memory: each is held
    (``size² x 16`` bytes: RGB and weight in float32), twice while the function is made."""
    from ..io.memory import available_memory

    need = 2 * used * size * size * 16
    have = available_memory()
    if need > have:
        fit = max(int(have // (2 * size * size * 16)), 1)
        raise FaceTransferError(
            f"--function keeps the texture of each of the {used} frames used: "
            f"{need / 2**30:.1f} GiB, more than the {have / 2**30:.1f} GiB available; give "
            f"--step {-(-used * step // fit)} or more, or a smaller --size")


def cmd_blend(args: argparse.Namespace) -> int:
    from ..composite import feather_mask, opencv_serves, poisson_blend

    out = _image_out(args.out, args, [args.source, args.target, args.mask])
    src = _read_image(args.source, "source image", deep=True)
    dst = _read_image(args.target, "target image", deep=True)
    if src.shape != dst.shape:
        raise FaceTransferError(f"source {args.source} is {src.shape[1]}x{src.shape[0]}, target "
                                f"{args.target} is {dst.shape[1]}x{dst.shape[0]}: sizes must match")
    mask = _read_mask(args.mask, dst.shape[:2])
    if not 0 <= args.feather < float("inf"):      # NaN was taken for none
        raise FaceTransferError(f"--feather must be a finite number >= 0 (pixels), got "
                                f"{args.feather}")
    m = feather_mask(mask, args.feather) if args.feather > 0 else mask
    method = args.method if args.feather == 0 else ("solver" if args.method == "auto" else args.method)
    src, dst = _same_depth(src, dst, args.target, out)
    if method == "opencv" and dst.dtype == np.uint16:
        raise FaceTransferError(f"--method opencv takes 8-bit images; the target {args.target} "
                                "is 16-bit: give --method solver or auto (16 bits kept)")
    if method == "opencv" and not opencv_serves(m):   # before: said as the library's keyword
        raise FaceTransferError(f"--method opencv needs a mask ({args.mask}) of one connected "
                                "region at least 2 pixels from the image border, and no "
                                "--feather; give --method solver or auto")
    res = poisson_blend(src, dst, m, method=method, mixed=args.mixed)
    res = _with_alpha(res, args.target, out)
    write_image(out, res, overwrite=args.overwrite)
    bits = ", 16-bit" if res.dtype == np.uint16 else ""
    kept = ", the target's alpha kept" if res.shape[2] == 4 else ""
    print(f"wrote {out} ({int(mask.sum())} masked pixels{bits}{kept})")
    return 0


def _with_alpha(res: np.ndarray, target: str, out: Path) -> np.ndarray:
    """The blend ``res`` with the target's alpha beside it (in ``res``'s bits: 8-bit alpha
    ``x 257``, 16-bit rounded, :func:`~facetransfer.io.frame_file.eight_bits`), where the
    target has one and ``out`` is a PNG; ``res`` as it is otherwise (a JPEG ``out``, an 8-bit
    RGBA TIFF target whose colour is stored premultiplied (associated alpha), or a float
    alpha: said in a warning naming the file)."""
    import logging

    from ..io.frame_file import eight_bits, sixteen_bits, tiff_alpha_kind
    from ..io.plate_alpha import image_alpha

    a = image_alpha(target)
    if a is None:
        return res
    why = (f"{out} holds none: written without it (give a .png to keep it)"
           if out.suffix.lower() != ".png" else
           "its colour is stored premultiplied (a TIFF's associated alpha): written without it"
           if tiff_alpha_kind(Path(target)) == "premultiplied" else
           f"its samples are {a.dtype}, not 8 or 16 bits: written without it"
           if a.dtype not in (np.uint8, np.uint16) else None)
    if why:
        logging.getLogger(__name__).warning("target %s has alpha; %s", target, why)
        return res
    if res.dtype == np.uint16:
        a = sixteen_bits(a)
    elif a.dtype == np.uint16:
        a = eight_bits(a)
    return np.dstack([res, a])


def _same_depth(src: np.ndarray, dst: np.ndarray, target: str, out: Path):
    """``src`` and ``dst`` in the target's bits (a 16-bit target's kept, the source's values
    ``8-bit x 257``), or in 8 where ``out`` is a JPEG (said in a warning naming the target)."""
    import logging

    from ..io.frame_file import eight_bits, sixteen_bits

    if dst.dtype == np.uint16 and out.suffix.lower() != ".png":
        logging.getLogger(__name__).warning(
            "target %s is 16-bit; %s holds 8 bits: written in 8 (give a .png to keep 16)",
            target, out)
        dst = eight_bits(dst)
    if dst.dtype == np.uint16:
        src = sixteen_bits(src)
    elif src.dtype == np.uint16:
        src = eight_bits(src)
    return src, dst


def register(sub) -> None:
    """Add ``texture default|lift|blend`` to the facetransfer parser."""
    tsub = add_command_group(sub, "texture", dest="texture_command",
                             help="face textures: default texture, lift from video, Poisson "
                             "blending (§6)",
                             description="Texture tools of Vlasic et al. 2005, §6.")

    d = tsub.add_parser("default", help="write the default face texture for a model's UVs (the "
                        "Lee Perry-Smith scan where it fits, else procedural skin)")
    d.add_argument("--model", help="model file (.npz) with UVs; default: the default model "
                   "(ict-arkit)")
    d.add_argument("--size", type=int, default=512, help="texture width and height (default 512)")
    d.add_argument("--seed", type=integer_from(0), default=0, help="noise seed (default 0)")
    d.add_argument("--source", choices=("procedural", "lee-perry-smith", "auto"),
                   default="auto",
                   help="auto (default): the Lee Perry-Smith scan fitted onto the ICT-FaceKit UVs "
                   "(CC-BY 3.0; first run ~15 s, then cached) where the model has ICT UVs, else "
                   "procedural skin; or force one of the two")
    d.add_argument("--out", required=True, help="TEX.png")
    d.add_argument("--overwrite", action="store_true", help="replace an existing output")
    d.set_defaults(func=cmd_default)

    lf = tsub.add_parser("lift", help="lift and merge a UV texture from a tracked video",
                         description="Sample every tracked frame onto the model's UVs, weight by "
                         "visibility and obliqueness, merge, fill holes.")
    lf.add_argument("video", help="the video the track belongs to")
    lf.add_argument("--track", required=True, help="TRACK.npz or CLIP.truth.npz")
    lf.add_argument("--model", help="model file (.npz) used for the track; default: the "
                    "default model, if the track was made with it")
    lf.add_argument("--size", type=int, default=512, help="texture size (default 512)")
    lf.add_argument("--step", type=int, default=1, help="use every STEP-th frame (default 1)")
    lf.add_argument("--function", help="also write the performance-driven texture function (.npz)")
    lf.add_argument("--k", type=int, default=None,
                    help="neighbours of the texture function (with --function; default 4)")
    lf.add_argument("--out", required=True, help="TEX.png (merged texture)")
    lf.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    lf.set_defaults(func=cmd_lift)

    b = tsub.add_parser("blend", help="Poisson-blend a source image into a target over a mask",
                        description="Poisson image editing (Pérez et al. 2003).")
    b.add_argument("--source", required=True, help="source image (same size as the target)")
    b.add_argument("--target", required=True, help="target image (its alpha, if any, kept in "
                   "a .png --out)")
    b.add_argument("--mask", required=True, help="mask image (white = paste)")
    b.add_argument("--method", choices=("auto", "opencv", "solver"), default="auto",
                   help="auto (default): OpenCV seamlessClone where it serves, else our solver")
    b.add_argument("--mixed", action="store_true", help="mixed gradients")
    b.add_argument("--feather", type=float, default=0.0, help="soft edge radius in pixels (default 0)")
    b.add_argument("--out", required=True, help="OUT.png")
    b.add_argument("--overwrite", action="store_true", help="replace an existing output")
    b.set_defaults(func=cmd_blend)
