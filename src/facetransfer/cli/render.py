"""``facetransfer render`` and ``facetransfer synth-video``: previews and synthetic footage (§6).

    facetransfer render --like identity=id03,expression=jawOpen --pose yaw=20 --out face.png
    facetransfer render MODEL.npz --weights 'identity=0.1,0.2,...;expression=...' --out face.png
    facetransfer synth-video --model MODEL.npz --random --frames 100 --seed 1 --out clip.mp4
    facetransfer synth-video --model MODEL.npz --performance perf.json --identity id02 --out clip.mp4

``synth-video`` writes ``clip.mp4`` and, beside it, ``clip.truth.npz`` (pose, weights per mode,
68 landmarks and all vertices in pixels, per-vertex visibility, per frame).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError
from ..io.atomic import check_output_path, write_image
from ..synth_keys import MAX_FRAMES  # of --frames and the spec's n_frames alike
from .common import (MODEL_ARG_HELP, add_video_options, frame_count, integer_from,
                     progress_disabled, resolve_model, video_options, video_out)

POSE_KEYS = ("yaw", "pitch", "roll", "scale")
#: The largest ``--pose`` angle, in degrees (a turn either way; 1e300 was taken) and scale.
MAX_POSE_ANGLE, MAX_POSE_SCALE = 360.0, 1000.0


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``."""
    w, sep, h = text.lower().partition("x")
    try:
        W, H = int(w), int(h)
    except ValueError:
        W = H = 0
    if not sep or not (8 <= W <= 8192 and 8 <= H <= 8192):
        raise FaceTransferError(f"--size: expected WIDTHxHEIGHT between 8 and 8192, got {text!r}")
    return W, H


def parse_pose(text: str | None) -> dict[str, float]:
    """``"yaw=10,pitch=-5,roll=0,scale=1.2"`` -> ``{"yaw": 10.0, ...}`` (missing keys omitted).

    Yaw, pitch and roll are render angles in degrees
    (:func:`facetransfer.render.rotation_from_euler`: ``R = Rz(roll) Ry(yaw) Rx(pitch)``; yaw > 0
    turns the face toward the image's right, pitch > 0 looks down, roll > 0 counter-clockwise).
    """
    out: dict[str, float] = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        name, sep, val = part.partition("=")
        name = name.strip()
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not sep or name not in POSE_KEYS or not np.isfinite(v):
            raise FaceTransferError(f"--pose: expected KEY=NUMBER with KEY in "
                                    f"{', '.join(POSE_KEYS)}, got {part!r}")
        out[name] = v
    if not 0 < out.get("scale", 1.0) <= MAX_POSE_SCALE:
        raise FaceTransferError(f"--pose: scale must be in (0, {MAX_POSE_SCALE:g}], got "
                                f"{out['scale']:g}")
    turned = {k: v for k, v in out.items() if k != "scale" and abs(v) > MAX_POSE_ANGLE}
    if turned:
        k = next(iter(turned))
        raise FaceTransferError(f"--pose: {k} must be in [-{MAX_POSE_ANGLE:g}, "
                                f"{MAX_POSE_ANGLE:g}] degrees, got {turned[k]:g}")
    return out


def parse_colour(text: str) -> tuple[int, int, int]:
    """``"255,255,255"`` -> ``(255, 255, 255)``."""
    try:
        c = tuple(int(v) for v in text.split(","))
    except ValueError:
        c = ()
    if len(c) != 3 or not all(0 <= v <= 255 for v in c):
        raise FaceTransferError(f"--background: expected R,G,B in 0..255, got {text!r}")
    return c  # type: ignore[return-value]


def parse_identity(text: str):
    """A label (``id03``) or comma-separated weights (``0.1,0.2,...``)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        return [float(p) for p in parts]
    except ValueError:
        if len(parts) > 1:
            raise FaceTransferError(f"--identity: expected a label or numbers, got {text!r}") \
                from None
        return parts[0]


def _face_pose(face, pose: dict[str, float]) -> dict[str, float]:
    """``--pose`` with a ``--face`` file's head rotation (``face``: read, or None; the page's
    ``Ry Rx Rz``) in the renderer's angles
    (:func:`facetransfer.render.cameras.euler_from_rotation`); ``--pose`` may give the scale
    only."""
    if face is None:
        return pose
    from ..face_file import face_rotation
    from ..render.cameras import euler_from_rotation

    turned = sorted(set(pose) - {"scale"})
    if turned:
        raise FaceTransferError(f"--pose {','.join(turned)}: the --face file gives the head's "
                                "rotation (--pose may give the scale)")
    yaw, pitch, roll = euler_from_rotation(face_rotation(face))
    return {**pose, "yaw": yaw, "pitch": pitch, "roll": roll}


def cmd_render(args: argparse.Namespace) -> int:
    from ..puppet_face import preview_face
    from .model import face_arg, face_or_weights

    out = check_output_path(args.out, overwrite=args.overwrite, inputs=[args.model, args.face])
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise FaceTransferError(f"--out {out}: expected a .png or .jpg image")
    size = parse_size(args.size)
    face = face_arg(args)
    pose = _face_pose(face, parse_pose(args.pose))
    background = parse_colour(args.background)   # before the model, which may be built first
    model = resolve_model(args.model)
    weights = face_or_weights(model, args, face)
    res = preview_face(model, weights, size=size, yaw_deg=pose.get("yaw", 0.0),
                       pitch_deg=pose.get("pitch", 0.0), roll_deg=pose.get("roll", 0.0),
                       scale=pose.get("scale", 1.0), background=background)
    write_image(out, res.image, overwrite=args.overwrite)
    print(f"wrote {out} ({size[0]}x{size[1]}, {int(res.visible.sum())} of "
          f"{res.visible.size} vertices visible)")
    return 0


def _texture(choice: str, model, seed: int):
    """``procedural`` -> None (synth's default), ``default`` -> the project's default face
    texture, anything else -> an image file."""
    if choice == "procedural":
        return None
    if model.uvs is None:
        raise FaceTransferError(f"--texture {choice}: the model has no UVs")
    if choice == "default":
        from ..texture import default_face_texture

        # the project's default face: Lee Perry-Smith on ICT UVs (§6 texture), else procedural
        return default_face_texture(model, seed=seed, source="auto")
    from ..synth import load_texture_image
    from ..texture.base import check_square_texture

    tex = load_texture_image(choice)           # the model's UV texture: square, as export's
    check_square_texture(tex.shape[1::-1], f"--texture {choice}", FaceTransferError)
    return tex


#: What each key of a performance spec is (:data:`facetransfer.synth.SPEC_KEYS`, in its order;
#: a key without one stops the import, so the help cannot leave one out).
_SPEC_KEY_HELP = {
    "n_frames": "clip length; default the last keyframe + 1, else 100", "fps": "default 25",
    "size": "[W, H], default [640, 480]",
    "identity": "a label such as id03, a weight list or a blend {label: amount}",
    "tracks": "{mode: [[frame, value], ...]} for each mode but the identity, a value a label, "
              "a blend or a weight list",
    "pose": "an oscillation {%s} or keyframes {keys: [[frame, {%s}], ...], fill}"}


def _performance_help() -> str:
    """``synth-video --performance``'s help: each key of the spec
    (:data:`facetransfer.synth.SPEC_KEYS`) with what it is."""
    from ..synth_keys import SPEC_KEYS    # facetransfer.synth's, without the renderer

    pose = _SPEC_KEY_HELP["pose"] % (", ".join(k for k in SPEC_KEYS["pose"] if k != "keys"),
                                     ", ".join(SPEC_KEYS["pose.keys"]))
    keys = ", ".join(f"{k} ({pose if k == 'pose' else _SPEC_KEY_HELP[k]})"
                     for k in SPEC_KEYS["spec"])
    return (f"performance spec, a JSON object of the keys {keys}; every key optional; "
            "--frames, --fps, --size and --identity replace theirs. "
            'E.g. {"n_frames": 50, "tracks": {"expression": [[0, "neutral"], [25, {"jawOpen": '
            '1}]]}, "pose": {"yaw_deg": 10}}. An unknown key is named with the known ones')


#: ``synth-video --performance``'s help: the spec's keys (:mod:`facetransfer.synth`).
PERFORMANCE_HELP = _performance_help()


def cmd_synth_video(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from ..synth import (DEFAULT_FPS, DEFAULT_SIZE, load_performance, performance_from_spec,
                         random_performance, synthesize_video, truth_path)

    from ..io.video import VIDEO_SUFFIXES, check_video_output
    from ..synth import truth_path as _truth_path

    vopt = video_options(args)
    inputs = [args.model, args.performance,
              args.texture if args.texture not in ("procedural", "default") else None]
    if Path(args.out).suffix.lower() not in VIDEO_SUFFIXES:  # its truth goes beside one file
        raise FaceTransferError(f"--out {args.out}: expected a video "
                                f"({', '.join(VIDEO_SUFFIXES)}; synth-video writes no image "
                                "sequence)")
    out = check_output_path(args.out, overwrite=args.overwrite, inputs=inputs)
    check_output_path(_truth_path(out), overwrite=args.overwrite, inputs=inputs)
    check_video_output(out, vopt, overwrite=args.overwrite)
    if bool(args.performance) == bool(args.random):
        raise FaceTransferError("give --performance SPEC.json or --random, not both" if
                                args.random else "give --performance SPEC.json or --random")
    if args.fps is not None and not 0 < args.fps <= 1000:
        raise FaceTransferError(f"--fps must be in (0, 1000], got {args.fps}")
    if args.frames is not None and not 1 <= args.frames <= MAX_FRAMES:
        raise FaceTransferError(f"--frames must be from 1 to {MAX_FRAMES}, got "
                                f"{args.frames}")
    if args.performance and not Path(args.performance).is_file():   # before the model's build
        raise FaceTransferError(f"performance spec {args.performance} does not exist")
    size = parse_size(args.size) if args.size else None
    identity = parse_identity(args.identity) if args.identity else None
    model = resolve_model(args.model)
    texture = _texture(args.texture, model, args.seed)
    if args.random:
        perf = random_performance(model, args.frames or 100, seed=args.seed,
                                  size=size or DEFAULT_SIZE, fps=args.fps or DEFAULT_FPS,
                                  identity=identity)
    else:
        perf = load_performance(model, args.performance)  # validates the file
        if size or args.fps or identity is not None or args.frames:
            spec = json.loads(Path(args.performance).read_text(encoding="utf-8"))
            if size:
                spec["size"] = list(size)
            if args.fps:
                spec["fps"] = args.fps
            if identity is not None:
                spec["identity"] = identity
            if args.frames:
                spec["n_frames"] = args.frames
            perf = performance_from_spec(model, spec)
    with tqdm(total=perf.n_frames, desc="synth-video", unit="frame",
              disable=progress_disabled()) as bar:
        truth = synthesize_video(model, perf, out, seed=args.seed, texture=texture,
                                 progress=bar.update, overwrite=args.overwrite, options=vopt)
    print(f"wrote {out} ({frame_count(perf.n_frames)}, {perf.size[0]}x{perf.size[1]} at "
          f"{perf.fps:g} fps) and {truth_path(out)}; mean vertex visibility "
          f"{truth.visible.mean():.2f}")
    return 0


def register(sub) -> None:
    """Add ``render`` and ``synth-video`` to the facetransfer parser."""
    from .model import add_face_options

    r = sub.add_parser("render", help="render a Lambert-shaded preview of a model face",
                       description="Render a model face (Eq. (5)) with a weak-perspective camera, "
                       "its eyes and mouth as the puppet's (eyeballs turned by an ARKit "
                       "model's eyeLook* weights, an open mouth's cavity).")
    r.add_argument("model", nargs="?", help=MODEL_ARG_HELP)
    add_face_options(r, face_takes=": its weights and head pose")
    r.add_argument("--pose", help="head pose, e.g. yaw=20,pitch=-5,roll=0,scale=1.2 (degrees)")
    r.add_argument("--size", default="640x480", help="image WIDTHxHEIGHT (default 640x480)")
    r.add_argument("--background", default="255,255,255", help="R,G,B (default white)")
    r.add_argument("--out", required=True, help="the image to write, IMG.png or .jpg")
    r.add_argument("--overwrite", action="store_true", help="replace an existing output")
    r.set_defaults(func=cmd_render)

    s = sub.add_parser("synth-video", help="render synthetic footage with exact ground truth",
                       description="Render a textured model face over a background with head "
                       "motion and expression/viseme tracks; writes CLIP.mp4 and "
                       "CLIP.truth.npz.")
    s.add_argument("--model", help=MODEL_ARG_HELP)
    s.add_argument("--identity", help="identity label or comma-separated weights")
    s.add_argument("--performance", metavar="SPEC.json", help=PERFORMANCE_HELP)
    s.add_argument("--random", action="store_true", help="a seeded random performance")
    s.add_argument("--frames", type=int, default=None,
                   help="number of frames (default 100 for --random; overrides the spec)")
    s.add_argument("--seed", type=integer_from(0), default=0,
                   help="seed of the random performance, texture and background")
    s.add_argument("--size", default=None, help="WIDTHxHEIGHT (default 640x480 or the spec's)")
    s.add_argument("--fps", type=float, default=None, help="frame rate (default 25 or the spec's)")
    s.add_argument("--texture", default="procedural",
                   help="'procedural' (default: band-limited skin, KLT-friendly), 'default' "
                   "(facetransfer.texture.default_face_texture) or a UV texture image file")
    s.add_argument("--out", required=True, type=video_out, help="CLIP.mp4")
    s.add_argument("--overwrite", action="store_true",
                   help="replace existing outputs (CLIP.mp4 and CLIP.truth.npz)")
    add_video_options(s, sequences=False, carries_target=False)  # beside its truth
    s.set_defaults(func=cmd_synth_video)
