"""Scans to model (Vlasic et al. 2005, §4.1–4.2): smoothing, feature points, template fitting.

Pipeline stages, one module each:

* :mod:`.meshops` — scan validation and repair, normals, Laplacian, closest points on a surface.
* :mod:`.smoothing` — non-iterative feature-preserving bilateral smoothing (Jones et al. 2003).
* :mod:`.features` — iBUG-68 feature-point files and the paper's marking protocols.
* :mod:`.detect` — feature points found automatically (MediaPipe on renderings of the scan).
* :mod:`.procrustes` — similarity alignment (Umeyama 1991).
* :mod:`.prior` — a linear face space fitted before the smooth deformation (ICT identity space).
* :mod:`.fitting` — template fitting (Allen et al. 2003; Sumner & Popović 2004) and the cascade.
* :mod:`.report` — surface-distance statistics and a picture of a fit.
* :mod:`.synthetic` — synthetic scans with exact ground truth (tests, benchmarks).
"""

from __future__ import annotations

from ..lazy import lazy_names

#: The public names and the submodule of each, imported on first use (PEP 562), as in
#: :mod:`facetransfer.datasets`: a submodule imported alone (:mod:`.procrustes`, a 3x3 SVD) ran
#: this file first, which imported the fitting and with it SciPy's sparse solvers.
_LAZY = {
    **dict.fromkeys(("IBUG_NAMES", "PROTOCOL_CLOSED_MOUTH_21", "PROTOCOL_NEUTRAL_42",
                     "PROTOCOL_VISEME_18", "FeaturePoints", "read_features",
                     "validate_features_on_surface", "write_features"), "features"),
    **dict.fromkeys(("FitDivergedError", "FitResult", "FitStage", "DEFAULT_SCHEDULE",
                     "PRIOR_SCHEDULE", "Template", "fit_template", "load_template"), "fitting"),
    **dict.fromkeys(("ScanMesh", "clean_scan", "load_scan"), "meshops"),
    **dict.fromkeys(("ShapePrior", "ict_prior", "model_identity_prior"), "prior"),
    **dict.fromkeys(("Similarity", "similarity_procrustes"), "procrustes"),
    **dict.fromkeys(("bilateral_smooth", "laplacian_smooth"), "smoothing"),
}

#: The submodules the eager imports left bound as attributes of the package
#: (``facetransfer.correspond.fitting`` after ``import facetransfer.correspond``), still so
_SUBMODULES = ("features", "fitting", "meshops", "prior", "procrustes", "smoothing")


__getattr__, __dir__ = lazy_names(__name__, _LAZY, _SUBMODULES)

__all__ = [
    "IBUG_NAMES", "PROTOCOL_CLOSED_MOUTH_21", "PROTOCOL_NEUTRAL_42", "PROTOCOL_VISEME_18",
    "FeaturePoints", "read_features", "validate_features_on_surface", "write_features",
    "FitDivergedError", "FitResult", "FitStage", "DEFAULT_SCHEDULE", "PRIOR_SCHEDULE", "Template",
    "fit_template", "ShapePrior", "ict_prior", "model_identity_prior",
    "load_template", "ScanMesh", "clean_scan", "load_scan", "Similarity", "similarity_procrustes",
    "bilateral_smooth", "laplacian_smooth",
]
