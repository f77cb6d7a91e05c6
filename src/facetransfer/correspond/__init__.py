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

from .features import (IBUG_NAMES, PROTOCOL_CLOSED_MOUTH_21, PROTOCOL_NEUTRAL_42, PROTOCOL_VISEME_18,
                       FeaturePoints, read_features, validate_features_on_surface, write_features)
from .fitting import (FitDivergedError, FitResult, FitStage, DEFAULT_SCHEDULE, PRIOR_SCHEDULE,
                      Template, fit_template, load_template)
from .meshops import ScanMesh, clean_scan, load_scan
from .prior import ShapePrior, ict_prior, model_identity_prior
from .procrustes import Similarity, similarity_procrustes
from .smoothing import bilateral_smooth, laplacian_smooth

__all__ = [
    "IBUG_NAMES", "PROTOCOL_CLOSED_MOUTH_21", "PROTOCOL_NEUTRAL_42", "PROTOCOL_VISEME_18",
    "FeaturePoints", "read_features", "validate_features_on_surface", "write_features",
    "FitDivergedError", "FitResult", "FitStage", "DEFAULT_SCHEDULE", "PRIOR_SCHEDULE", "Template",
    "fit_template", "ShapePrior", "ict_prior", "model_identity_prior",
    "load_template", "ScanMesh", "clean_scan", "load_scan", "Similarity", "similarity_procrustes",
    "bilateral_smooth", "laplacian_smooth",
]
