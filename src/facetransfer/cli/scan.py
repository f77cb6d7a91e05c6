"""``facetransfer scan``: scans to model (§4.1–4.2): smoothing and template fitting."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)

LPS_CREDIT = "Lee Perry-Smith (Infinite Realities), CC-BY 3.0"


def register(sub) -> None:
    """Add ``scan smooth`` and ``scan fit`` to the facetransfer parser."""
    p = sub.add_parser("scan", help="smooth scans and fit the template to them (§4.1-4.2)",
                       description="Scans to model: bilateral smoothing and template fitting.")
    ssub = p.add_subparsers(dest="scan_command", metavar="SCAN_COMMAND")
    ssub.required = True

    sm = ssub.add_parser("smooth", help="bilateral (Jones et al. 2003) smoothing of a scan")
    sm.add_argument("scan", help="scan mesh (OBJ, PLY, STL, GLB …)")
    sm.add_argument("--out", required=True, help="output mesh (duplicate vertices merged)")
    sm.add_argument("--sigma-c", type=float, default=None,
                    help="spatial sigma, scan units (default: 2 x mean edge length)")
    sm.add_argument("--sigma-s", type=float, default=None,
                    help="influence sigma, scan units (default: sigma-c / 2)")
    sm.set_defaults(func=_smooth)

    ft = ssub.add_parser("fit", help="fit the template to a scan; writes OUT, OUT.report.json, OUT.png")
    ft.add_argument("scan", help="scan mesh (any units and pose)")
    ft.add_argument("--features", required=True,
                    help='JSON {"points": {"36": [x, y, z], ...}} of iBUG-68 points on the scan (>= 8)')
    ft.add_argument("--template", default="ict",
                    help="'ict' (ICT-FaceKit face area, default), a model .npz, or a mesh "
                         "(with --template-landmarks)")
    ft.add_argument("--template-landmarks", default=None,
                    help="JSON list of 68 template vertex indices (-1 = none) for a mesh template")
    ft.add_argument("--reference", default=None,
                    help="previous fit of the same subject (template topology) to deform instead: "
                         "closed-mouth scan -> neutral fit, viseme -> closed-mouth fit")
    ft.add_argument("--protocol", choices=("neutral", "closed-mouth", "viseme"), default=None,
                    help="use only that marking protocol's feature points (42, 21 or 18)")
    ft.add_argument("--out", required=True, help="fitted mesh (template topology, scan coordinates)")
    ft.add_argument("--no-progress", action="store_true", help="no progress bar")
    ft.set_defaults(func=_fit)


def _smooth(args) -> int:
    from ..correspond import bilateral_smooth, load_scan
    from ..io.atomic import check_output_path
    from ..io.mesh import write_mesh

    check_output_path(args.out)
    for name in ("sigma_c", "sigma_s"):
        val = getattr(args, name)
        if val is not None and not val > 0:
            raise ValueError(f"--{name.replace('_', '-')} must be positive, got {val}")
    scan = load_scan(args.scan)
    v = bilateral_smooth(scan.vertices, scan.faces, sigma_c=args.sigma_c, sigma_s=args.sigma_s)
    write_mesh(args.out, v, scan.faces)
    print(f"wrote {args.out} ({len(v)} vertices)")
    return 0


def _fit(args) -> int:
    import numpy as np

    from ..correspond import fit_template, load_scan, load_template, read_features
    from ..correspond.report import plot_fit, write_fit_report
    from ..errors import MeshError
    from ..io.atomic import check_output_path
    from ..io.mesh import read_mesh, write_mesh

    out = Path(args.out)
    check_output_path(out)
    stem = out.with_suffix("")
    report_path, png_path = Path(f"{stem}.report.json"), Path(f"{stem}.png")
    features = read_features(args.features, protocol=args.protocol)
    scan = load_scan(args.scan)
    template = load_template(args.template, landmarks=args.template_landmarks)
    reference = None
    if args.reference:
        reference = read_mesh(args.reference).vertices
        if reference.shape != template.vertices.shape:
            raise MeshError(f"reference {args.reference} has {len(reference)} vertices; the template "
                            f"has {len(template.vertices)} (it must be a fit in template topology)")
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=1, desc="fitting", unit="stage", leave=False)

    def progress(i, n, name):
        if bar is not None:
            bar.total = n
            bar.n = i
            bar.set_postfix_str(name)
            bar.refresh()

    try:
        result = fit_template(scan, features, template, reference=reference, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    credit = LPS_CREDIT if "leeperrysmith" in Path(args.scan).name.lower() else None
    write_fit_report(report_path, result, scan=str(args.scan), features=str(args.features),
                     template=str(args.template), credit=credit)
    plot_fit(png_path, result, title=f"fit of {Path(args.scan).name}", credit=credit)
    write_mesh(out, result.vertices, result.faces)
    s = result.stats
    print(f"wrote {out}, {report_path}, {png_path}: surface distance mean {s['mean']:.4g}, "
          f"median {s['median']:.4g}, p95 {s['p95']:.4g}, max {s['max']:.4g} (scan units), "
          f"{s['seconds']:.1f} s")
    if not np.isfinite(s["mean"]):
        return 1
    return 0
