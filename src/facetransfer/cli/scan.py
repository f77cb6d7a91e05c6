"""``facetransfer scan``: scans to model (§4.1–4.2): smoothing and template fitting."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def _credit(scan) -> str | None:
    """The Lee Perry-Smith credit line for that scan's outputs, None for other scans."""
    from ..texture import LEE_PERRY_SMITH_CREDIT

    return LEE_PERRY_SMITH_CREDIT if "leeperrysmith" in Path(scan).name.lower() else None


def _add_texture_options(p, prefix: str = "") -> None:
    """``--texture`` and ``--flip-v``: the colour map used to find feature points."""
    p.add_argument("--texture", default=None,
                   help=prefix + "the scan's colour map (default: one embedded in the mesh file; "
                   "without one the scan is shaded in a skin tone)")
    p.add_argument("--flip-v", action="store_true",
                   help=prefix + "the texture coordinates count v downwards (e.g. some glTF "
                   "exports)")


def register(sub) -> None:
    """Add ``scan smooth`` and ``scan fit`` to the facetransfer parser."""
    p = sub.add_parser("scan", help="smooth scans and fit the template to them (§4.1-4.2)",
                       description="Scans to model: bilateral smoothing and template fitting.")
    ssub = p.add_subparsers(dest="scan_command", metavar="SCAN_COMMAND")
    ssub.required = True

    sm = ssub.add_parser("smooth", help="bilateral (Jones et al. 2003) smoothing of a scan")
    sm.add_argument("scan", help="scan mesh (OBJ, PLY, STL, GLB …)")
    sm.add_argument("--out", required=True, help="output mesh, .obj, .ply, .stl, .off or .glb "
                    "(duplicate vertices merged)")
    sm.add_argument("--sigma-c", type=float, default=None,
                    help="spatial sigma, scan units (default: 2 x mean edge length)")
    sm.add_argument("--sigma-s", type=float, default=None,
                    help="influence sigma, scan units (default: sigma-c / 2)")
    sm.add_argument("--overwrite", action="store_true", help="replace an existing output")
    sm.set_defaults(func=_smooth)

    fe = ssub.add_parser("features", help="find iBUG-68 feature points on a scan automatically "
                         "(MediaPipe on renderings); writes OUT (JSON) and a picture")
    fe.add_argument("scan", help="scan mesh (any units and pose)")
    fe.add_argument("--out", required=True, help='feature file to write (JSON {"points": ...})')
    _add_texture_options(fe)
    fe.add_argument("--view", choices=("auto", "front"), default="auto",
                    help="auto (default): search the scan's orientation; front: it faces +z "
                         "with y up")
    fe.add_argument("--with-jaw", action="store_true",
                    help="also the jaw contour (iBUG 0-16; a silhouette, less reliable on a 3D "
                    "surface)")
    fe.add_argument("--picture", default=None,
                    help="rendering with the points drawn (default OUT with suffix .png)")
    fe.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    fe.set_defaults(func=_features)

    ft = ssub.add_parser("fit", help="fit the template to a scan; writes OUT, OUT.report.json, OUT.png")
    ft.add_argument("scan", help="scan mesh (any units and pose)")
    ft.add_argument("--features", default="auto",
                    help='JSON {"points": {"36": [x, y, z], ...}} of iBUG-68 points on the scan '
                    '(>= 8), or "auto" (the default): found as by "scan features" (written to '
                    'OUT with suffix .features.json)')
    _add_texture_options(ft, prefix="with --features auto: ")
    ft.add_argument("--template", default="ict",
                    help="'ict' (ICT-FaceKit face area, default), a model .npz, or a mesh "
                         "(with --template-landmarks)")
    ft.add_argument("--template-landmarks", default=None,
                    help="JSON list of 68 template vertex indices (-1 = none) for a mesh template")
    ft.add_argument("--reference", default=None,
                    help="previous fit of the same subject (template topology) to deform instead: "
                         "closed-mouth scan -> neutral fit, viseme -> closed-mouth fit")
    ft.add_argument("--prior", choices=("auto", "identity+expression", "none"), default="auto",
                    help="face space fitted before the smooth deformation: 'auto' (default) = for the "
                         "ICT template, both ICT-FaceKit's 100 identity components and "
                         "identity+expression are fitted and the one closer to the scan is kept "
                         "(the report names it), none for other "
                         "templates; 'identity+expression' (ICT template) adds the "
                         "FaceKit's expression shapes, for a scan in an expression without a "
                         "neutral fit to give as --reference; 'none' = the paper's generic "
                         "template alone. Not used with --reference")
    ft.add_argument("--protocol", choices=("neutral", "closed-mouth", "viseme"), default=None,
                    help="use only that marking protocol's feature points (42, 21 or 18)")
    ft.add_argument("--out", required=True, help="fitted mesh, .obj, .ply, .stl, .off or .glb "
                    "(template topology, scan coordinates)")
    ft.add_argument("--no-progress", action="store_true", help="no progress bar")
    ft.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    ft.set_defaults(func=_fit)


def _smooth(args) -> int:
    from ..correspond import bilateral_smooth, load_scan
    from ..io.atomic import check_output_path
    from ..io.mesh import check_mesh_output, write_mesh
    from .common import tqdm_progress

    check_mesh_output(args.out)
    check_output_path(args.out, overwrite=args.overwrite, inputs=[args.scan])
    for name in ("sigma_c", "sigma_s"):
        val = getattr(args, name)
        if val is not None and not 0 < val < float("inf"):   # inf and NaN were taken
            raise ValueError(f"--{name.replace('_', '-')} must be a positive finite number "
                             f"(scan units), got {val}")
    scan = load_scan(args.scan)
    on_progress, close = tqdm_progress("scan smooth", unit="chunk")   # off: --no-progress
    try:
        v = bilateral_smooth(scan.vertices, scan.faces, sigma_c=args.sigma_c,
                             sigma_s=args.sigma_s, progress=on_progress)
    finally:
        close()
    write_mesh(args.out, v, scan.faces, overwrite=args.overwrite)
    print(f"wrote {args.out} ({len(v)} vertices)")
    return 0


def _embedded_texture(path):
    """The colour map embedded in a mesh file (trimesh), as (H, W, 3) uint8, or None."""
    import numpy as np
    import trimesh

    try:
        m = trimesh.load(path, process=False, force="mesh")
        mat = m.visual.material
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
    except Exception:  # no visual, no material, unreadable: no texture
        return None
    return None if img is None else np.asarray(img.convert("RGB"), np.uint8)


def _features(args) -> int:
    from ..correspond.detect import INNER_FEATURES
    from ..io.atomic import check_output_path
    from ..io.output_names import check_output_suffix

    out = Path(args.out)
    picture = Path(args.picture) if args.picture else out.with_suffix(".png")
    inputs = [args.scan, args.texture]
    check_output_suffix(out, (".json",), "a feature-point file")
    check_output_suffix(picture, (".png", ".jpg", ".jpeg"), "the picture of the points",
                        flag="--picture")
    check_output_path(out, overwrite=args.overwrite, inputs=inputs)
    check_output_path(picture, overwrite=args.overwrite, inputs=inputs + [out])
    ids = tuple(range(68)) if args.with_jaw else INNER_FEATURES
    d = _detect(args.scan, args.texture, args.flip_v, args.view, ids)
    _write_detected(out, picture, args.scan, d)
    print(f"wrote {out} ({len(d.features.indices)} points) and {picture}")
    return 0


def _detect(scan, texture_path, flip_v: bool, view: str, ids):
    """Feature points found on renderings of a scan file (``scan features``)."""
    from ..correspond.detect import detect_scan_features
    from ..errors import MeshError
    from ..io.mesh import read_mesh
    from ..synth import load_texture_image

    mesh = read_mesh(scan)
    if len(mesh.faces) == 0:
        raise MeshError(f"{scan} has no triangles (a point cloud cannot be rendered)")
    texture = load_texture_image(texture_path) if texture_path else _embedded_texture(scan)
    uvs = None
    if texture is not None:
        if mesh.uvs is None:
            raise MeshError(f"{scan} has no texture coordinates for its colour map")
        uvs = mesh.uvs.copy()
        if flip_v:
            uvs[:, 1] = 1.0 - uvs[:, 1]
    return detect_scan_features(mesh.vertices, mesh.faces, uvs=uvs, texture=texture,
                                view=view, ids=ids)


def _write_detected(out, picture, scan, d) -> None:
    """The feature file and its picture (the rendering with the points drawn)."""
    import cv2

    from ..correspond.features import IBUG_NAMES, write_features
    from ..io.atomic import write_image

    credit = _credit(scan)
    extra = {"scan": Path(scan).name,
             "note": "found by facetransfer scan features: MediaPipe face landmarker on a "
                     "rendering of the scan, lifted onto its surface",
             "names": {str(int(i)): IBUG_NAMES[int(i)] for i in d.features.indices}}
    if credit:
        extra["credit"] = credit
    img = cv2.cvtColor(d.image, cv2.COLOR_RGB2BGR)
    for (x, y), i in zip(d.points2d, d.features.indices):
        cv2.circle(img, (int(round(x)), int(round(y))), 3, (0, 255, 255), -1, cv2.LINE_AA)
    if credit:
        cv2.putText(img, credit, (8, img.shape[0] - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (255, 255, 255), 1, cv2.LINE_AA)
    write_image(picture, cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    write_features(out, d.features, extra=extra)


def _fit(args) -> int:
    import numpy as np

    from ..correspond import fit_template, load_scan, load_template
    from ..correspond.report import plot_fit, write_fit_report
    from ..io.mesh import check_mesh_output, write_mesh

    _check_fit_options(args)
    out = check_mesh_output(args.out)
    stem = out.with_suffix("")
    report_path, png_path = Path(f"{stem}.report.json"), Path(f"{stem}.png")
    inputs = _check_fit_outputs(args, (out, report_path, png_path))
    features = _fit_features(args, stem, inputs)
    scan = load_scan(args.scan)
    template = load_template(args.template, landmarks=args.template_landmarks)
    reference = _fit_reference(args.reference, template)
    prior = _fit_prior(args.prior, args.template, template, reference)
    bar = _StageBar(enabled=not args.no_progress)
    try:
        result = fit_template(scan, features, template, reference=reference, prior=prior,
                              progress=bar)
    finally:
        bar.close()
    credit = _credit(args.scan)
    write_fit_report(report_path, result, scan=str(args.scan), features=str(args.features),
                     template=str(args.template), credit=credit, repairs=scan.notes)
    plot_fit(png_path, result, title=f"fit of {Path(args.scan).name}", credit=credit)
    write_mesh(out, result.vertices, result.faces)
    _print_fit_summary((out, report_path, png_path), result.stats, scan.notes)
    return 0 if np.isfinite(result.stats["mean"]) else 1


def _unused_fit_option(args) -> str | None:
    """The first ``scan fit`` option given where it does nothing (it was ignored in silence),
    with why; None if every one given acts."""
    found_here = "with --features auto (the points found on the scan's rendering)"
    if args.features != "auto":
        if args.texture is not None:
            return f"--texture acts only {found_here}"
        if args.flip_v:
            return f"--flip-v acts only {found_here}"
    if args.template_landmarks is not None and (   # as correspond.load_template tells them
            args.template == "ict" or Path(args.template).suffix.lower() == ".npz"):
        return (f"--template-landmarks is for a mesh template; the {args.template} template "
                "has its own landmarks")
    if args.reference and args.prior == "identity+expression":
        return "--prior is not used with --reference (the reference fit is deformed)"
    return None


def _check_fit_options(args) -> None:
    """Refuse, in one line, an option that would be ignored (:func:`_unused_fit_option`)."""
    from ..errors import FaceTransferError

    why = _unused_fit_option(args)
    if why is not None:
        raise FaceTransferError(f"{why}: leave it out")


def _check_fit_outputs(args, outputs) -> list:
    """Refuse existing outputs (without --overwrite) and outputs that are inputs; the inputs."""
    from ..io.atomic import check_output_path

    inputs = [args.scan, args.features if args.features != "auto" else None, args.texture,
              args.reference, args.template_landmarks,
              args.template if args.template != "ict" else None]
    for o in outputs:
        check_output_path(o, overwrite=args.overwrite, inputs=inputs)
    return inputs


def _fit_features(args, stem: Path, inputs: list):
    """The feature points of ``scan fit``: read from --features, or found (``auto``) and written
    to STEM.features.json (then ``args.features`` names that file, for the report)."""
    from ..correspond import read_features

    if args.features != "auto":
        return read_features(args.features, protocol=args.protocol)
    from ..correspond.detect import INNER_FEATURES
    from ..correspond.features import PROTOCOLS
    from ..io.atomic import check_output_path

    fpath = Path(f"{stem}.features.json")
    check_output_path(fpath, overwrite=args.overwrite, inputs=inputs)
    ids = PROTOCOLS[args.protocol] if args.protocol else INNER_FEATURES
    d = _detect(args.scan, args.texture, args.flip_v, "auto", ids)
    _write_detected(fpath, Path(f"{stem}.features.png"), args.scan, d)
    print(f"wrote {fpath} ({len(d.features.indices)} feature points found automatically)")
    args.features = str(fpath)
    return d.features


def _fit_reference(path, template):
    """The --reference fit's vertices ``(n, 3)`` (template topology), or None."""
    from ..errors import MeshError
    from ..io.mesh import read_mesh

    if not path:
        return None
    reference = read_mesh(path).vertices
    if reference.shape != template.vertices.shape:
        raise MeshError(f"reference {path} has {len(reference)} vertices; the template "
                        f"has {len(template.vertices)} (it must be a fit in template topology)")
    return reference


def _fit_prior(choice: str, template_arg: str, template, reference):
    """The ``prior`` argument of fit_template for --prior."""
    from ..errors import MeshError

    if choice == "none":
        return None
    if choice == "identity+expression":
        if template.name != "ict":
            raise MeshError(f"--prior identity+expression needs the ICT template, not {template_arg}")
        from ..correspond.prior import ict_prior

        return ict_prior("identity+expression", neutral=template.vertices)
    if template.name == "ict" and reference is None:   # auto: the better of the two face spaces
        from ..correspond.prior import ict_prior

        return [template.prior, ict_prior("identity+expression", neutral=template.vertices)]
    return "template"


class _StageBar:
    """A tqdm bar over the fitting stages, called as ``progress(i, n, name)`` by fit_template."""

    def __init__(self, *, enabled: bool):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            from .common import progress_disabled

            self.bar = tqdm(total=1, desc="fitting", unit="stage", leave=False,
                            disable=progress_disabled())

    def __call__(self, i: int, n: int, name: str) -> None:
        if self.bar is not None:
            self.bar.total = n
            self.bar.n = i
            self.bar.set_postfix_str(name)
            self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _print_fit_summary(paths, s: dict, notes) -> None:
    """The lines ``scan fit`` prints: outputs and distances, the prior chosen, the repairs."""
    out, report_path, png_path = paths
    print(f"wrote {out}, {report_path}, {png_path}: surface distance mean {s['mean']:.4g}, "
          f"median {s['median']:.4g}, p95 {s['p95']:.4g}, max {s['max']:.4g} (scan units), "
          f"{s['seconds']:.1f} s")
    if notes:
        print("scan repaired: " + "; ".join(notes))
    if s.get("prior"):   # last, as the README says: the prior and each candidate's residual
        cands = s["prior"].get("candidates") or []
        rule = s["prior"].get("chosen_by", "the lowest residual")
        print(f"shape prior: {s['prior']['name']}" + (
            f" (chosen automatically by {rule}: " + ", ".join(
                f"{c['name']} {c['residual']:.4g}" for c in cands)
            + f"; {s['prior'].get('residual_units', 'work units')})" if cands else ""))
