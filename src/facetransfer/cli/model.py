"""``facetransfer model``: build, inspect, sample and picture multilinear face models (§4).

    facetransfer model build --dataset ict-bilinear --out bilinear.npz
    facetransfer model info bilinear.npz
    facetransfer model synth bilinear.npz --like identity=id03,expression=jawOpen --out face.obj
    facetransfer model sheet bilinear.npz --out sheet.png        # also writes sheet_dials.png
    facetransfer model dials bilinear.npz [--out dials.png]      # semantic identity dials
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import sys
from pathlib import Path

import numpy as np

from ..default_model import dataset_ranks as default_ranks  # the recipe ranks
from ..errors import DatasetError, FaceTransferError, ShapeError
from ..io.atomic import atomic_path, check_output_path
from ..io.memory import available_memory  # a name of this module: tests replace it
from .common import (MODEL_ARG_HELP, add_command_group, check_output_name, integer_from,
                     progress_shown, resolve_model, tqdm_progress)

log = logging.getLogger(__name__)

#: Sheet tile size (W, H) in pixels.
TILE = (150, 180)


# --------------------------------------------------------------------------------- parsing
def parse_ranks(text: str | None) -> dict[str, int]:
    """``"identity=9,expression=6"`` -> ``{"identity": 9, "expression": 6}``."""
    if not text:
        return {}
    out: dict[str, int] = {}
    for part in text.split(","):
        name, sep, val = part.partition("=")
        name = name.strip()
        try:
            r = int(val)
        except ValueError:
            r = 0
        if not sep or not name or r < 1:
            raise FaceTransferError(f"--ranks: expected MODE=POSITIVE_INT[,...], got {part!r}")
        _once(out, name, "--ranks", text)
        out[name] = r
    return out


def parse_weights(text: str) -> dict[str, np.ndarray]:
    """``"identity=0.1,0.2;expression=1,0"`` -> per-mode float arrays."""
    out: dict[str, np.ndarray] = {}
    for part in text.split(";"):
        if not part.strip():
            continue
        name, sep, vals = part.partition("=")
        try:
            w = np.array([float(x) for x in vals.split(",")], dtype=np.float64)
        except ValueError:
            w = np.array([np.nan])
        if not sep or not name.strip() or w.size == 0 or not np.all(np.isfinite(w)):
            raise FaceTransferError(f"--weights: expected MODE=NUM,NUM,...[;MODE=...], got {part!r}")
        _once(out, name.strip(), "--weights", text)
        out[name.strip()] = w
    if not out:
        raise FaceTransferError("--weights is empty")
    return out


def parse_like(text: str) -> dict[str, str]:
    """``"identity=id03,expression=jawOpen"`` -> ``{"identity": "id03", "expression": "smile"}``."""
    out: dict[str, str] = {}
    for part in text.split(","):
        name, sep, lab = part.partition("=")
        if not sep or not name.strip() or not lab.strip():
            raise FaceTransferError(f"--like: expected MODE=LABEL[,...], got {part!r}")
        _once(out, name.strip(), "--like", text)
        out[name.strip()] = lab.strip()
    return out


def _once(parsed: dict, mode: str, flag: str, text: str) -> None:
    """Refuse a mode ``flag`` gives twice (the last one was taken without a word)."""
    if mode in parsed:
        raise FaceTransferError(f"{flag} gives mode {mode!r} twice, in {text!r}: give each "
                                "mode once")


# --------------------------------------------------------------------------------- build


def _fill_missing(dataset, method: str, seed: int):
    """Impute missing cells (§4.4) or raise listing them. Returns (dataset, imputed mask or None)."""
    if dataset.mask.all():
        return dataset, None
    missing = dataset.missing_cells()
    shown = "; ".join("/".join(c) for c in missing[:12])
    more = f" and {len(missing) - 12} more" if len(missing) > 12 else ""
    if method == "none":
        raise DatasetError(f"{len(missing)} missing cells ({shown}{more}); use --impute ppca or "
                           "average to fill them")
    try:
        from ..impute import impute_dataset
    except ImportError:
        raise DatasetError(f"{len(missing)} missing cells ({shown}{more}) and imputation is not "
                           "available in this version") from None
    cb, close = tqdm_progress(f"impute ({method})")
    try:
        res = impute_dataset(dataset, method=method, rng=np.random.default_rng(seed), progress=cb)
    finally:
        close()
    imputed = np.asarray(res.imputed, dtype=bool)
    cells = [list(c) for c in missing]
    filled = res.dataset.with_vertices(res.dataset.vertices, np.ones_like(dataset.mask),
                                       imputed_cells=cells, impute_method=method)
    print(f"imputed {int(imputed.sum())} missing cells ({method})", file=sys.stderr)
    return filled, imputed


#: peak memory of a build as a multiple of the data tensor (data set, tensor, unfoldings, SVD)
BUILD_MEMORY_FACTOR = 4.0


def build_memory_estimate(dataset: str, n_identities: int | None) -> int | None:
    """Peak bytes :func:`cmd_build` needs for an ICT data set (None for other data sets).

    The data tensor holds ``identities x cells x vertices x 3`` float64 values (Fig. 3); the build
    keeps about :data:`BUILD_MEMORY_FACTOR` copies of it at its peak.
    """
    from ..datasets import ICT_DATASETS
    from ..datasets.ict import REGIONS, load_recipes

    if dataset not in ICT_DATASETS:
        return None
    spec = load_recipes()["datasets"][dataset]
    n_id = int(spec["n_identities"] if n_identities is None else n_identities)
    cells = 1
    for mode in ("expressions", "visemes"):
        if mode in spec:
            cells *= len(spec[mode])
    return int(BUILD_MEMORY_FACTOR * n_id * cells * REGIONS["face"] * 3 * 8)


def check_build_memory(dataset: str, n_identities: int | None) -> None:
    """Refuse a build that cannot fit in memory, naming the estimate and what is available."""
    need = build_memory_estimate(dataset, n_identities)
    have = available_memory()
    if need is not None and need > have:
        raise FaceTransferError(
            f"--identities {n_identities}: building {dataset} needs about {need / 2**30:.1f} GiB "
            f"of memory, this machine has {have / 2**30:.1f} GiB available; use fewer identities")


def cmd_build(args: argparse.Namespace) -> int:
    from .. import assets
    from ..datasets import ICT_DATASETS, load_dataset
    from ..model import build_model

    check_output_name(args.out, (".npz",), "a model")
    check_output_path(args.out, overwrite=args.overwrite, inputs=[args.dataset])
    ranks = parse_ranks(args.ranks)
    if args.identities is not None and args.identities < 2:
        raise FaceTransferError(f"--identities must be at least 2, got {args.identities}")
    check_build_memory(str(args.dataset), args.identities)
    assets.set_download_progress(progress_shown())
    cb, close = tqdm_progress(f"dataset {args.dataset}")
    try:
        ds = load_dataset(args.dataset, seed=args.seed, n_identities=args.identities, progress=cb)
    finally:
        close()
    if args.identities is not None and str(args.dataset) not in ICT_DATASETS:
        log.warning("--identities applies to the ICT data sets only; ignored")
    ds, imputed = _fill_missing(ds, args.impute, args.seed)
    use = default_ranks(ds)
    use.update(ranks)
    for m, r in ranks.items():
        if m in ds.mode_names and r > ds.shape[ds.mode_names.index(m)]:
            raise ShapeError(f"--ranks {m}={r} is larger than the {ds.shape[ds.mode_names.index(m)]} "
                             f"{m} entries of {args.dataset}")
    model = build_model(ds, use, refine=args.refine, imputed=imputed)
    model.save(args.out, overwrite=args.overwrite)
    err = model.provenance.get("relative_errors", [float("nan")])[-1]
    print(f"wrote {args.out}: modes {', '.join(f'{n}={d}->{r}' for n, d, r in zip(model.mode_names, model.shape, model.ranks))}, "
          f"{model.n_vertices} vertices, relative error {err:.4f}")
    from ..arkit import arkit_shortfall, arkit_truncated

    if arkit_truncated(model):     # ARKit-named, truncated: said before the model is used
        print(f"note: its tracks will carry no ARKit activations (no exports): "
              f"{arkit_shortfall(model)}")
    return 0


# --------------------------------------------------------------------------------- info
def explained_variance(model) -> dict[str, list[float]]:
    """Fraction of each mode's data variance held by each kept component."""
    out = {}
    for name, ev, r in zip(model.mode_names, model.eigenvalues, model.ranks):
        ev = np.asarray(ev, dtype=np.float64)
        tot = ev.sum()
        out[name] = [float(x) for x in (ev[:r] / tot if tot > 0 else np.zeros(r))]
    return out


def _short(value, width: int = 88) -> str:
    """A provenance value in at most about ``width`` characters: a long list as its first
    items and its length, a dict as its keys, text cut with an ellipsis."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return f"{len(value)} rows of {len(value[0])} values"
    if isinstance(value, list) and len(json.dumps(value, default=str)) > width:
        head = json.dumps(value[:4], default=str)[:-1]
        return f"{head}, ... ({len(value)} items)]"
    if isinstance(value, dict) and len(json.dumps(value, default=str)) > width:
        keys = list(value)
        return "{" + ", ".join(keys[:8]) + (f", ... ({len(keys)} keys)" if len(keys) > 8
                                            else "") + "}"
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= width else text[:width - 3] + "..."


def cmd_info(args: argparse.Namespace) -> int:
    m = resolve_model(args.model)
    if args.json:
        print(json.dumps({"mode_names": list(m.mode_names), "shape": list(m.shape),
                          "ranks": list(m.ranks), "labels": [list(x) for x in m.labels],
                          "explained_variance": explained_variance(m),
                          "provenance": m.provenance}, indent=1, default=str))
        return 0
    ev = explained_variance(m)
    lines = [f"model {args.model or 'ict-arkit (the default model)'}",
             f"  vertices: {m.n_vertices}, triangles: {len(m.faces)}, "
             f"landmarks: {'yes' if m.landmarks is not None else 'no'}, "
             f"uvs: {'yes' if m.uvs is not None else 'no'}"]
    for name, d, r, labs in zip(m.mode_names, m.shape, m.ranks, m.labels):
        per = ", ".join(f"{x:.3g}" for x in ev[name][:4]) + (", ..." if r > 4 else "")
        lines.append(f"  mode {name}: {d} training entries, rank {r}, explained variance "
                     f"{float(np.sum(ev[name])):.6f}")
        lines.append(f"    per component: {per}")
        lines.append(f"    labels: {_short(', '.join(labs))}" + (f" ({len(labs)})"
                                                                   if len(labs) > 12 else ""))
    if m.imputed is not None and np.any(m.imputed):
        lines.append(f"  imputed cells: {int(np.sum(m.imputed))}")
    lines.append("  provenance (--json: all of it):")
    lines += [f"    {k}: {_short(v)}" for k, v in sorted(m.provenance.items())]
    print("\n".join(lines))
    return 0


# --------------------------------------------------------------------------------- synth
def synth_weights(model, weights: dict[str, np.ndarray] | None = None,
                  like: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """Weights for :meth:`MultilinearModel.synthesize`: given modes set, others at their mean."""
    w = model.default_weights()
    if like:
        w = model.like(**like)
    for name, vec in (weights or {}).items():
        k = model.mode_index(name)
        if vec.shape != (model.ranks[k],):
            raise ShapeError(f"--weights {name} has {vec.size} values; the model's {name} rank is "
                             f"{model.ranks[k]}")
        w[model.mode_names[k]] = model.check_reach(k, vec, "--weights")
    return w


def add_face_options(p, *, face_takes: str = "") -> None:
    """Add ``--weights``, ``--like`` and ``--face``: the three ways to name one face of the
    model (one definition; read back by :func:`face_arg` and :func:`face_or_weights`).
    ``face_takes``: what the command takes of a ``--face`` file besides its weights, said
    after its help (``": its weights and head pose"``)."""
    p.add_argument("--weights", help="per-mode weights, e.g. 'identity=0.1,0.2,...;expression=...' "
                   "(modes not given: their mean)")
    p.add_argument("--like", help="training rows by label, e.g. identity=id03,expression=jawOpen")
    p.add_argument("--face", metavar="FACE.json", help="a face saved by the dial editor "
                   "(`facetransfer view`'s Save face) of this model" + face_takes)


def face_arg(args):
    """The ``--face`` file read (:func:`facetransfer.face_file.read_face`; None without one),
    once ``--face``, ``--weights`` and ``--like`` are known to be given one at most."""
    given = [o for o, v in (("--face", getattr(args, "face", None)), ("--weights", args.weights),
                            ("--like", args.like)) if v]
    if len(given) > 1:
        raise FaceTransferError("give one of --face, --weights and --like, not "
                                + " and ".join(given))
    if given != ["--face"]:
        return None
    from ..face_file import read_face

    return read_face(args.face)


def face_or_weights(model, args, face) -> dict[str, np.ndarray]:
    """The weights of ``face`` (a face saved by the dial editor, :func:`face_arg`), else of
    ``--weights`` / ``--like`` (:func:`synth_weights`), for ``model synth`` and ``render``:
    a refusal of a face dialled on another model names their positional MODEL, not
    ``--model`` (:func:`positional_hint`)."""
    if face is not None:
        from ..face_file import FaceFileError, face_weights

        try:
            return face_weights(face, model)
        except FaceFileError as err:
            raise FaceFileError(positional_hint(str(err), "MODEL")) from None
    return synth_weights(model, parse_weights(args.weights) if args.weights else None,
                         parse_like(args.like) if args.like else None)


def positional_hint(message: str, model_arg: str) -> str:
    """``message`` (a refusal of a file made with another model,
    :func:`facetransfer.model_hint.model_hint`) for a command whose model is its positional
    ``model_arg``, not ``--model``: "leave out --model" -> "leave out MODEL", "give --model P"
    -> "give P as MODEL"."""
    message = message.replace("leave out --model", f"leave out {model_arg}")
    return re.sub(r"give --model (.+?)\)$", rf"give \1 as {model_arg})", message)


def _unturned(face) -> str:
    """What ``synth``'s line adds for a ``--face`` whose head is turned: the mesh is not."""
    if face is None or not any(face.head):
        return ""
    return ("; in the model's frame, without the face file's head turn (yaw {:.3g}, pitch {:.3g}, "
            "roll {:.3g}; `render --face` shows it)".format(*face.head))


def cmd_synth(args: argparse.Namespace) -> int:
    from ..io.mesh import check_mesh_output, write_mesh

    out = check_mesh_output(args.out)
    check_output_path(out, overwrite=args.overwrite, inputs=[args.model, args.face])
    face = face_arg(args)
    m = resolve_model(args.model)
    v = m.synthesize(face_or_weights(m, args, face))
    write_mesh(out, v, m.faces, uvs=m.uvs if out.suffix.lower() == ".obj" else None,
               overwrite=args.overwrite)
    print(f"wrote {out} ({m.n_vertices} vertices)" + _unturned(face))
    return 0


# --------------------------------------------------------------------------------- sheet
def _fallback_render(vertices: np.ndarray, faces: np.ndarray, camera, size) -> np.ndarray:
    """Lambert-shaded painter's algorithm (numpy + matplotlib) when facetransfer.render is absent."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    W, H = size
    R, s, t = camera.rotation, camera.scale, camera.translation
    X = vertices @ R.T
    xy = s * X[:, :2] * np.array([1.0, -1.0]) + t
    tri = xy[faces]
    n = np.cross(X[faces[:, 1]] - X[faces[:, 0]], X[faces[:, 2]] - X[faces[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    keep = n[:, 2] > 0
    shade = 0.25 + 0.75 * np.clip(n[:, 2], 0, 1)
    order = np.argsort(X[faces, 2].mean(axis=1)[keep])
    fig = plt.figure(figsize=(W / 100, H / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    ax.axis("off")
    col = np.repeat(shade[keep][order, None], 3, axis=1) * np.array([0.85, 0.75, 0.7])
    ax.add_collection(PolyCollection(tri[keep][order], facecolors=col, edgecolors="none"))
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return img


#: The skin of a sheet's tiles (RGB in [0, 1]).
TILE_SKIN = (0.85, 0.75, 0.70)


def _render_tile(vertices: np.ndarray, faces: np.ndarray, camera, size) -> np.ndarray:
    try:
        from ..render import render
    except ImportError:
        return _fallback_render(vertices, faces, camera, size)
    colors = np.tile(np.array([TILE_SKIN]), (len(vertices), 1))
    return render(vertices, faces, camera, size, colors=colors, background=(255, 255, 255)).image


def tile_painter(model):
    """``paint(V, weights, camera, size=TILE) -> (H, W, 3) uint8``: a sheet's tile of
    ``model``'s face ``V`` (n, 3) made of ``weights`` (mode -> (r_k,)), its eyes and mouth as
    the puppet's (:func:`facetransfer.puppet_face.draw_face`; an ARKit model's eyes turned by
    the weights' eyeLook*): the eye holes and the mouth gap showed the sheet's white paper."""
    from ..arkit import is_arkit_model, weights_to_activations
    from ..puppet_face import draw_face
    from ..topology import mesh_topology

    topo, arkit = mesh_topology(model, lips=False), is_arkit_model(model)

    def paint(V: np.ndarray, weights, camera, size=TILE) -> np.ndarray:
        acts = weights_to_activations(model, np.asarray(weights["expression"])[None])[0] \
            if arkit else None
        return draw_face(model, topo, V, camera, size, activations=acts,
                         colour=TILE_SKIN, weights=weights).image
    return paint


def _camera(vertices: np.ndarray, size, yaw_deg: float = 15.0):
    """A weak-perspective camera framing ``vertices`` (render's helper, or the same by hand),
    the head turned by ``yaw_deg`` degrees about the model's y axis (positive: toward the
    image's right; :func:`facetransfer.render.rotation_from_euler` with no pitch or roll)."""
    try:
        from ..render import look_at_weak_perspective, rotation_from_euler
    except ImportError:
        from types import SimpleNamespace

        a = np.deg2rad(yaw_deg)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        Y = vertices @ R[:2].T
        lo, hi = Y.min(axis=0), Y.max(axis=0)
        s = 0.85 * min(size) / max(float((hi - lo).max()), 1e-12)
        c = (lo + hi) / 2
        t = np.array([(size[0] - 1) / 2 - s * c[0], (size[1] - 1) / 2 + s * c[1]])
        return SimpleNamespace(scale=s, rotation=R, translation=t)
    return look_at_weak_perspective(vertices, size, rotation=rotation_from_euler(yaw_deg, 0.0),
                                    fill=0.85)


def _grid(tiles: list[list[np.ndarray]], row_labels: list[str], col_labels: list[str],
          title: str) -> "object":
    from PIL import Image, ImageDraw

    th, tw = tiles[0][0].shape[:2]
    lw, hh = 90, 36
    img = Image.new("RGB", (lw + tw * len(col_labels), hh + th * len(row_labels)), "white")
    draw = ImageDraw.Draw(img)
    draw.text((4, 2), title, fill=(0, 0, 0))
    for j, lab in enumerate(col_labels):
        draw.text((lw + j * tw + 4, hh - 14), lab[:22], fill=(0, 0, 0))
    for i, lab in enumerate(row_labels):
        draw.text((4, hh + i * th + th // 2), lab[:14], fill=(0, 0, 0))
        for j, t in enumerate(tiles[i]):
            img.paste(Image.fromarray(t), (lw + j * tw, hh + i * th))
    return img


def model_sheets(model, *, max_identities: int = 8, dial_components: int = 3,
                 dial_steps: tuple[float, ...] = (-2.0, -1.0, 0.0, 1.0, 2.0)):
    """Two PIL images: identities × attribute labels (Fig. 5/6), and one dial at a time.

    The first sheet has one row per training identity (up to ``max_identities``) and one column
    per training label of every other mode (that mode's training row, the remaining modes at
    their mean). The second varies one principal direction of one mode's training weights at a
    time by ``dial_steps`` standard deviations, all other weights at their mean.
    """
    ident = model.mode_names[0]
    ids = list(model.labels[0][:max_identities])
    cols: list[tuple[str, str]] = [(m, lab) for m, labs in zip(model.mode_names[1:], model.labels[1:])
                                   for lab in labs]
    weights = [[model.like(**{ident: i, m: lab}) for m, lab in cols] for i in ids]
    mean = model.default_weights()
    cam = _camera(model.synthesize(mean), TILE)
    flat = [w for row in weights for w in row]
    batch = {n: np.stack([w[n] for w in flat]) for n in model.mode_names}
    V = model.synthesize(batch)
    paint = tile_painter(model)
    tiles = [[paint(V[i * len(cols) + j], weights[i][j], cam) for j in range(len(cols))]
             for i in range(len(ids))]
    col_labels = [lab if len(model.mode_names) == 2 else f"{m[:3]}:{lab}" for m, lab in cols]
    sheet = _grid(tiles, ids, col_labels, f"{', '.join(model.mode_names)} "
                  f"(ranks {', '.join(map(str, model.ranks))})")

    rows, rlabels = [], []
    for name in model.mode_names:
        C = model.weight_cov(name)
        ev, vec = np.linalg.eigh(C)
        order = np.argsort(ev)[::-1][:dial_components]
        for pc, c in enumerate(order, start=1):
            step = np.sqrt(max(ev[c], 0.0)) * vec[:, c]
            ws = []
            for t in dial_steps:
                w = dict(mean)
                w[name] = mean[name] + t * step
                ws.append(w)
            b = {n: np.stack([w[n] for w in ws]) for n in model.mode_names}
            Vd = model.synthesize(b)
            rows.append([paint(v, w, cam) for v, w in zip(Vd, ws)])
            rlabels.append(f"{name} pc{pc}")
    dials = _grid(rows, rlabels, [f"{t:+g} sd" for t in dial_steps], "one dial at a time")
    return sheet, dials


def cmd_sheet(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise FaceTransferError(f"--out must end in .png, got {out}")
    dials_out = out.with_name(f"{out.stem}_dials.png")
    if args.max_identities < 1:
        raise FaceTransferError(f"--max-identities must be >= 1, got {args.max_identities}")
    for o in (out, dials_out):
        check_output_path(o, overwrite=args.overwrite, inputs=[args.model])
    m = resolve_model(args.model)
    sheet, dials = model_sheets(m, max_identities=args.max_identities)
    with atomic_path(out, overwrite=args.overwrite) as tmp, \
            atomic_path(dials_out, overwrite=args.overwrite) as tmp2:
        sheet.save(tmp, format="PNG")
        dials.save(tmp2, format="PNG")
    print(f"wrote {out} and {dials_out}")
    return 0


# --------------------------------------------------------------------------------- dials
def cmd_dials(args: argparse.Namespace) -> int:
    from ..dials import dial_sheet, learn_dials

    if args.out:
        if Path(args.out).suffix.lower() != ".png":
            raise FaceTransferError(f"--out must end in .png, got {args.out}")
        check_output_path(args.out, overwrite=args.overwrite, inputs=(args.model,))
    m = resolve_model(args.model)
    dials = learn_dials(m)
    lines = [f"identity dials of {args.model or 'the default model'} (learnt from "
             f"{m.shape[0]} identities; one unit = one standard deviation of the measurement; "
             f"{dials.unit})",
             f"  {'dial':14s} {'R2':>6s} {'LOO R2':>7s} {'sd':>8s} {'+1 unit':>9s}  measures"]
    for d in dials.dials:
        lines.append(f"  {d.name:14s} {d.r2:6.3f} {d.r2_loo:7.3f} {d.sigma:8.3f} "
                     f"{d.effect:+9.3f}  {d.description}")
    print("\n".join(lines))
    bad = dials.unreliable()
    if bad:
        print(f"note: {', '.join(bad)}: leave-one-out R2 <= 0, no better than the mean for an "
              f"identity left out: {m.shape[0]} identities are too few for "
              + ("them" if len(bad) > 1 else "it") + " to mean what the name says")
    if args.out:
        img = dial_sheet(m, dials, paint=tile_painter(m))
        with atomic_path(args.out, overwrite=args.overwrite) as tmp:
            img.save(tmp, format="PNG")
        print(f"wrote {args.out}")
    return 0


# --------------------------------------------------------------------------------- register
def _overwrite_option(p) -> None:
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing output (an output is never one of the inputs)")


def register(sub) -> None:
    """Add ``facetransfer model {build,info,synth,sheet,dials}``."""
    msub = add_command_group(sub, "model", dest="model_command",
                             help="build multilinear face models (§4), describe them (info), "
                             "write faces (synth), picture sheets and identity dials",
                             description="Multilinear face models (Vlasic et al. 2005, §4).")

    b = msub.add_parser("build", help="build a model from a data set")
    b.add_argument("--dataset", required=True,
                   help="ict-arkit, ict-bilinear, ict-trilinear, a manifest .csv, or a "
                   "FaceWarehouse folder")
    b.add_argument("--ranks", help="ranks per mode, e.g. identity=9,expression=6 "
                   "(default: 40/52 ict-arkit, 9/6 ict-bilinear, 16/4/4 ict-trilinear, full "
                   "otherwise)")
    b.add_argument("--refine", action=argparse.BooleanOptionalAction, default=True,
                   help="refine the N-mode SVD by alternating least squares (default on)")
    b.add_argument("--impute", choices=("ppca", "average", "none"), default="ppca",
                   help="how to fill missing cells (default ppca; none: missing cells are an error)")
    b.add_argument("--seed", type=integer_from(0), default=0,
                   help="seed of ICT identities and imputation")
    b.add_argument("--identities", type=int, default=None,
                   help="number of identities (ICT data sets only; default 50 ict-arkit, 15 "
                   "ict-bilinear, 16 ict-trilinear)")
    b.add_argument("--out", required=True, help="model file to write (.npz)")
    _overwrite_option(b)
    b.set_defaults(func=cmd_build)

    i = msub.add_parser("info", help="show a model's modes, ranks, variance and provenance")
    i.add_argument("model", nargs="?", help=MODEL_ARG_HELP)
    i.add_argument("--json", action="store_true", help="everything, provenance whole, as JSON")
    i.set_defaults(func=cmd_info)

    s = msub.add_parser("synth", help="write one face of the model as a mesh")
    s.add_argument("model", nargs="?", help=MODEL_ARG_HELP)
    add_face_options(s)
    s.add_argument("--out", required=True,
                   help="the mesh to write: FACE.obj (with the model's uvs), .ply, .stl, .off "
                   "or .glb")
    _overwrite_option(s)
    s.set_defaults(func=cmd_synth)

    h = msub.add_parser("sheet", help="picture sheets: identities x expressions, and dials")
    h.add_argument("model", nargs="?", help=MODEL_ARG_HELP)
    h.add_argument("--out", required=True, help="SHEET.png (also writes SHEET_dials.png)")
    h.add_argument("--max-identities", type=int, default=8,
                   help="rows of the first sheet, one per training identity (default 8)")
    _overwrite_option(h)
    h.set_defaults(func=cmd_sheet)

    dl = msub.add_parser("dials", help="semantic identity dials (face width, nose length, ...) "
                         "with R², and a picture sheet")
    dl.add_argument("model", nargs="?", help=MODEL_ARG_HELP)
    dl.add_argument("--out", metavar="DIALS.png", help="also draw the dials (mean face at -2, 0, "
                    "+2 units)")
    dl.add_argument("--overwrite", action="store_true", help="replace an existing picture")
    dl.set_defaults(func=cmd_dials)
