"""Missing data (Vlasic et al. 2005, §4.4): fill the empty cells of an incomplete Cartesian product.

A data set of corresponded meshes is a tensor ``T`` of shape ``(3 n, d_1, ..., d_K)`` (vertex mode
first, Fig. 3) with whole *cells* ``(i_1, ..., i_K)`` missing: when a mesh is missing, all its
``3 n`` coordinates are missing together.

For every attribute mode ``j`` the mode-``j`` vectors of ``T`` are treated as samples of a
probabilistic PCA ``C_j = W_j W_j^T + σ_j² I``; the missing values solve the stacked
conditional-mean equations of all modes, alternated with the PPCA fits (an EM that never raises
its objective; details in :mod:`facetransfer.impute.joint`).

Modules
-------
==============  ============================================================================
``ppca``        probabilistic PCA [Tipping & Bishop 1999]: fit, likelihood, conditional mean
``cells``       the mask of known cells and the checks every method shares
``joint``       the paper's scheme: the joint linear system, its E- and M-steps,
                :func:`impute_tensor`
``regions``     face regions: covariances per soft region (§4.4's mouth emphasis)
``baselines``   averaging (Blanz et al. 2003), §4.4's naive imputation, tensorly's masked
                Tucker
``methods``     the methods by name (:data:`METHODS`), :func:`impute_dataset`
``evaluate``    hide cells, predict, score (§4.4 "Evaluation", Fig. 4)
==============  ============================================================================

References
----------
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4.
Tipping & Bishop 1999, "Probabilistic principal component analysis", J. R. Stat. Soc. B 61(3).
Blanz, Basso, Poggio, Vetter 2003, "Reanimating faces in images and video", Eurographics.
Salakhutdinov & Roweis 2003, "Adaptive overrelaxed bound optimization methods", ICML.
"""

from .baselines import average_impute, naive_impute, reference_indices, tensorly_impute
from .cells import validate_mask
from .evaluate import (EVAL_VARIANTS, EvalRecord, ImputeEvaluation, evaluate_imputation,
                       random_holdout)
from .joint import (MAX_CELLS, TensorImputation, impute_tensor, joint_operator, mode_operator,
                    mode_scatters, solve_missing)
from .methods import METHODS, ImputeResult, impute_dataset, impute_tensor_by
from .ppca import PPCA, conditional_mean, ppca_fit, ppca_incomplete, ppca_nll
from .regions import dataset_regions, impute_tensor_regions, region_memberships

__all__ = [
    "METHODS",
    "MAX_CELLS",
    "PPCA",
    "ppca_fit",
    "ppca_nll",
    "conditional_mean",
    "ppca_incomplete",
    "validate_mask",
    "mode_scatters",
    "mode_operator",
    "joint_operator",
    "solve_missing",
    "TensorImputation",
    "impute_tensor",
    "average_impute",
    "naive_impute",
    "tensorly_impute",
    "ImputeResult",
    "impute_dataset",
    "dataset_regions",
    "region_memberships",
    "impute_tensor_regions",
    "EVAL_VARIANTS",
    "impute_tensor_by",
    "reference_indices",
    "random_holdout",
    "EvalRecord",
    "ImputeEvaluation",
    "evaluate_imputation",
]
