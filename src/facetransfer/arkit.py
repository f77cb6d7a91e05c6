"""Apple's 52 ARKit blendshapes as a model's expression mode: names, and activations <-> weights.

A model built from the ``ict-arkit`` data set (§4.1) has the expression labels ``"neutral"``
followed by ARKit blendshape names. Its expression mode is kept untruncated (§4.3), so the
expression weights of Eq. (5) and the blendshape *activations* ``a`` (one number in [0, 1] per
ARKit shape, as ARKit, Live Link Face and MediaPipe report them) convert into each other exactly:

    w = U[0] + Dᵀ a,   D = U[1:] - U[0]                                         (Eq. A)

where ``U`` is the expression factor (row 0 the neutral). Contracting the model with an identity
(Eq. (9)) then gives that person's blendshape rig: ``f(a) = f_0 + Σ_j a_j (f_j - f_0)``.

:data:`ARKIT_NAMES` is the canonical order of every activation array in facetransfer
(``TRACK.npz`` key ``blendshapes``): MediaPipe Face Landmarker's blendshape order (without its
``_neutral``), which is alphabetical, followed by ``tongueOut``, the one ARKit shape MediaPipe
does not report. Shapes a model lacks (``tongueOut`` for the FaceKit) have activation 0.

References
----------
Vlasic et al. 2005, §4.3, Eq. (5), (9); Apple, ARKit ``ARFaceAnchor.BlendShapeLocation``;
MediaPipe Face Landmarker blendshape categories.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from .errors import ShapeError

__all__ = ["ARKIT_NAMES", "MEDIAPIPE_NAMES", "load_facekit_mapping", "is_arkit_model",
           "arkit_rows", "activation_basis", "activations_to_weights", "weights_to_activations",
           "ExpressionRig", "expression_rig", "attach_activations", "activation_prior_scale"]

#: MediaPipe Face Landmarker's 51 ARKit blendshapes, in its output order (after ``_neutral``).
MEDIAPIPE_NAMES: tuple[str, ...] = (
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight",
    "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft",
    "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight",
    "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight", "mouthFunnel",
    "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight",
    "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
    "mouthShrugUpper", "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight", "noseSneerLeft",
    "noseSneerRight",
)

#: The 52 ARKit blendshapes in facetransfer's order: MediaPipe's 51, then ``tongueOut``.
ARKIT_NAMES: tuple[str, ...] = MEDIAPIPE_NAMES + ("tongueOut",)

_NEUTRAL = "neutral"


@lru_cache(maxsize=1)
def load_facekit_mapping() -> dict:
    """The packaged table ``arkit_facekit.json``: ARKit name -> FaceKit shape weights.

    Returns
    -------
    dict
        ``{"shapes": {arkit_name: {facekit_file: weight}}, "not_modelled": …, "dropped": …}``.
    """
    text = resources.files("facetransfer.data").joinpath("arkit_facekit.json").read_text()
    table = json.loads(text)
    unknown = set(table["shapes"]) - set(ARKIT_NAMES)
    if unknown:  # a packaging error, not user input
        raise ShapeError(f"arkit_facekit.json names non-ARKit shapes {sorted(unknown)}")
    return table


@lru_cache(maxsize=1)
def activation_prior_scale() -> np.ndarray:
    """Relative ridge per ARKit shape when activations are fitted to 2-D points, (52,).

    From ``arkit_facekit.json`` (``prior_scale``; 1 where not listed): shapes that real
    performances use often and that 2-D points show well (jaw, blinks, smiles, brows) get a
    weaker prior than shapes that mostly mimic them in 2-D (lip-only opening, funnel, puff).
    """
    table = load_facekit_mapping().get("prior_scale", {})
    return np.array([float(table.get(n, 1.0)) for n in ARKIT_NAMES])


def _expression_mode(model) -> int | None:
    return model.mode_names.index("expression") if "expression" in model.mode_names else None


def is_arkit_model(model) -> bool:
    """Whether the model's expression mode is ``neutral`` + ARKit-named shapes, untruncated.

    Only then do expression weights and activations convert exactly (Eq. A).
    """
    k = _expression_mode(model)
    if k is None:
        return False
    labels = model.labels[k]
    if len(labels) < 2 or labels[0] != _NEUTRAL or not set(labels[1:]) <= set(ARKIT_NAMES):
        return False
    return model.ranks[k] >= len(labels) - 1


def arkit_truncated(model) -> bool:
    """Whether the model's expressions are ARKit-named but its expression mode is truncated
    (so that they convert to no activations, :func:`is_arkit_model`)."""
    k = _expression_mode(model)
    labels = () if k is None else model.labels[k]
    return (len(labels) >= 2 and labels[0] == _NEUTRAL and set(labels[1:]) <= set(ARKIT_NAMES)
            and model.ranks[k] < len(labels) - 1)


def arkit_shortfall(model) -> str | None:
    """Why a model's tracks carry no ARKit activations (None: they do,
    :func:`is_arkit_model`): its expressions are not ARKit-named, or they are but the
    expression mode is truncated (the activations convert from all of its components). A
    clause that names the model itself ("the model's expressions ..."), to follow a colon."""
    if is_arkit_model(model):
        return None
    if arkit_truncated(model):
        k = _expression_mode(model)
        labels = model.labels[k]
        return (f"the model's expression mode keeps {model.ranks[k]} of its {len(labels)} components "
                f"(the ARKit activations need at least {len(labels) - 1}: build it without "
                "truncating the expression rank)")
    return ("the model's expressions are not ARKit blendshapes (the default model's, ict-arkit, "
            "are)")


def arkit_rows(model) -> np.ndarray:
    """For each of the 52 :data:`ARKIT_NAMES`, its training row in the expression factor.

    Returns
    -------
    (52,) int64
        Row index (>= 1), or -1 where the model has no such shape (its activation is 0).
    """
    if not is_arkit_model(model):
        raise ShapeError("the model's expressions are not ARKit blendshapes (build it from the "
                         "'ict-arkit' data set)")
    labels = model.labels[_expression_mode(model)]
    return np.array([labels.index(n) if n in labels else -1 for n in ARKIT_NAMES], np.int64)


def activation_basis(model) -> tuple[np.ndarray, np.ndarray]:
    """``U[0]`` and ``D`` of Eq. (A) over the 52 ARKit names.

    Returns
    -------
    u0 : (r,) float64
        The neutral's expression weights.
    D : (52, r) float64
        Row j: ``U[row_j] - U[0]``; zero for shapes the model lacks.
    """
    U = model.factors[_expression_mode(model)]
    rows = arkit_rows(model)
    D = np.zeros((len(ARKIT_NAMES), U.shape[1]))
    ok = rows >= 0
    D[ok] = U[rows[ok]] - U[0]
    return U[0].copy(), D


def activations_to_weights(model, activations: np.ndarray) -> np.ndarray:
    """Expression weights from ARKit activations, Eq. (A).

    Parameters
    ----------
    activations : (..., 52) float

    Returns
    -------
    (..., r_expression) float64
    """
    a = np.asarray(activations, dtype=np.float64)
    if a.shape[-1:] != (len(ARKIT_NAMES),):
        raise ShapeError(f"activations must be (..., {len(ARKIT_NAMES)}), got {a.shape}")
    u0, D = activation_basis(model)
    return u0 + a @ D


def weights_to_activations(model, weights: np.ndarray, *, clip: bool = True) -> np.ndarray:
    """ARKit activations from expression weights: the least-squares inverse of Eq. (A).

    Exact for weights made by :func:`activations_to_weights` (the expression mode is
    untruncated, so ``D`` has full row rank over the shapes the model has).

    Parameters
    ----------
    weights : (..., r_expression) float
    clip : bool
        Clip to [0, 1] (the activation range).

    Returns
    -------
    (..., 52) float64
        0 for shapes the model lacks.
    """
    u0, D = activation_basis(model)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape[-1:] != u0.shape:
        raise ShapeError(f"expression weights must be (..., {u0.size}), got {w.shape}")
    ok = np.any(D != 0, axis=1)
    sol, *_ = np.linalg.lstsq(D[ok].T, (w - u0).reshape(-1, u0.size).T, rcond=None)
    a = np.zeros(w.shape[:-1] + (len(ARKIT_NAMES),))
    a[..., ok] = sol.T.reshape(w.shape[:-1] + (int(ok.sum()),))
    return np.clip(a, 0.0, 1.0) if clip else a


@dataclass(frozen=True)
class ExpressionRig:
    """One person's ARKit blendshape rig from the model (Eq. (9) with Eq. (A)).

    Attributes
    ----------
    neutral : (n, 3) float64
        The person's neutral face.
    deltas : (52, n, 3) float64
        ``f_j - f_0`` per ARKit name (zero for shapes the model lacks).
    names : tuple of str
        :data:`ARKIT_NAMES`.
    """

    neutral: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...] = ARKIT_NAMES

    def shape(self, activations: np.ndarray) -> np.ndarray:
        """Vertices ``(..., n, 3)`` for activations ``(..., 52)``."""
        a = np.asarray(activations, dtype=np.float64)
        if a.shape[-1:] != self.deltas.shape[:1]:
            raise ShapeError(f"activations must be (..., {self.deltas.shape[0]}) (one per name "
                             f"of {len(self.names)}), got {a.shape}")
        return self.neutral + np.tensordot(a, self.deltas, axes=([-1], [0]))


def expression_rig(model, weights: dict, *, vertices: np.ndarray | None = None) -> ExpressionRig:
    """The blendshape rig of the face with ``weights`` (its identity; the expression is ignored).

    Parameters
    ----------
    model : MultilinearModel
        ARKit-named expression mode (:func:`is_arkit_model`).
    weights : dict mode name -> (r,) array
    vertices : (m,) int array, optional
        Only these vertices.
    """
    k = _expression_mode(model)
    u0, D = activation_basis(model)
    w = dict(weights)
    w[model.mode_names[k]] = u0
    B = model.mode_basis(k, w, vertices=vertices)  # (n, 3, r), Eq. (9)
    neutral = B @ u0
    deltas = np.einsum("ncr,jr->jnc", B, D)
    return ExpressionRig(neutral, deltas)


def attach_activations(track, model):
    """The track with ``blendshapes`` recomputed from its expression weights (Eq. A inverse).

    A track of a model whose expressions are not ARKit blendshapes is returned without them.

    Parameters
    ----------
    track : facetransfer.track.Track
    model : MultilinearModel
        The model the track's weights belong to.
    """
    import dataclasses

    if not is_arkit_model(model) or "expression" not in track.weights:
        return dataclasses.replace(track, blendshapes=None, blendshape_names=None)
    a = weights_to_activations(model, track.weights["expression"]).astype(np.float32)
    return dataclasses.replace(track, blendshapes=a, blendshape_names=ARKIT_NAMES)
