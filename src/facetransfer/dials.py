"""Semantic identity dials: linear directions in identity space that mean measurable things.

The paper's §5 introduction recalls Allen et al. (2003), who map intuitive features (height,
weight) to shape-space weights by linear regression. Here the features are measurements of the
face (:data:`MEASUREMENTS`: face width, jaw width, nose length, eye spacing, lip fullness, …,
distances between iBUG-68 landmark vertices of the neutral face, in model units: centimetres for
the ICT-FaceKit models). They are measured on every training identity of the model, and each is
regressed on the identity weights (ridge regression; the ridge is chosen by leave-one-out error,
so the reported R² does not flatter a model with as many components as identities)::

    m_k(w) ≈ c_k + b_kᵀ (w - w̄)                                           (Eq. D1)

The dial of measurement ``k`` moves the identity weights along the regression direction ``b_k``,
scaled so that one unit changes the measurement, measured on the mean identity ``w̄``, by one
standard deviation ``σ_k`` of that measurement over the training identities::

    w ← w + t d_k,   d_k = σ_k b_k / (m_k(w̄ + b_k) - m_k(w̄))                  (Eq. D2)

(Scaling by the measured change rather than by ``b_kᵀ b_k`` keeps the unit honest where the
ridge shrinks ``b_k``.) :attr:`Dial.effect` is the change one unit makes on the mean identity
(the "stated amount" that ``facetransfer model dials`` lists); measurements are distances,
nearly linear in ``w``, so it holds for other identities too (tested and measured).

References
----------
Vlasic et al. 2005, §5 (introduction) and Eq. (9); B. Allen, B. Curless, Z. Popović, "The space
of human body shapes", SIGGRAPH 2003, §5.2 (feature analysis).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from .errors import FaceTransferError

log = logging.getLogger(__name__)

__all__ = ["MEASUREMENTS", "Dial", "DialSet", "DialError", "measure", "neutral_weights",
           "identity_measurements", "learn_dials", "parse_dial_values", "dial_track",
           "dial_sheet"]


class DialError(FaceTransferError):
    """Unknown dial, malformed dial values, or a model without landmarks / identities."""


def _d(i: int, j: int) -> Callable[[np.ndarray], np.ndarray]:
    return lambda L: np.linalg.norm(L[..., i, :] - L[..., j, :], axis=-1)


def _eye_spacing(L: np.ndarray) -> np.ndarray:
    return np.linalg.norm(L[..., 36:42, :].mean(-2) - L[..., 42:48, :].mean(-2), axis=-1)


def _eye_width(L: np.ndarray) -> np.ndarray:
    return 0.5 * (_d(36, 39)(L) + _d(42, 45)(L))


def _lips(L: np.ndarray) -> np.ndarray:
    return _d(51, 62)(L) + _d(57, 66)(L)


#: name -> (description, function of iBUG-68 landmark positions (..., 68, 3) -> (...)).
MEASUREMENTS: dict[str, tuple[str, Callable[[np.ndarray], np.ndarray]]] = {
    "width": ("face width (jaw outline at the ears, landmarks 0-16)", _d(0, 16)),
    "jaw_width": ("jaw width (landmarks 4-12)", _d(4, 12)),
    "height": ("face height (nasion to chin, landmarks 27-8)", _d(27, 8)),
    "nose_length": ("nose length (nasion to nose base, landmarks 27-33)", _d(27, 33)),
    "nose_width": ("nose width (alar base, landmarks 31-35)", _d(31, 35)),
    "eye_spacing": ("eye spacing (between the eye centres)", _eye_spacing),
    "eye_width": ("eye width (corner to corner, mean of both eyes)", _eye_width),
    "mouth_width": ("mouth width (corners, landmarks 48-54)", _d(48, 54)),
    "lip_fullness": ("lip fullness (upper + lower lip height, 51-62 + 57-66)", _lips),
    "chin_length": ("chin length (lower lip to chin, landmarks 57-8)", _d(57, 8)),
}


@dataclass(frozen=True)
class Dial:
    """One semantic dial (Eq. D1, D2).

    Attributes
    ----------
    name, description : str
    direction : (r,) float64
        ``d_k``: identity-weight change per unit.
    sigma : float
        ``σ_k``: standard deviation of the measurement over the training identities: the
        intended change per unit.
    effect : float
        Measured change per unit on the mean identity (model units).
    r2 : float
        In-sample R² of Eq. (D1).
    r2_loo : float
        Leave-one-out R² of Eq. (D1) (predictive; can be negative).
    """

    name: str
    description: str
    direction: np.ndarray
    sigma: float
    effect: float
    r2: float
    r2_loo: float


@dataclass(frozen=True)
class DialSet:
    """The dials of one model: ``dials``, the identity ``mode`` and the measurement ``unit``."""

    dials: tuple[Dial, ...]
    mode: str = "identity"
    unit: str = "model units"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.dials)

    def get(self, name: str) -> Dial:
        for d in self.dials:
            if d.name == name:
                return d
        raise DialError(f"unknown identity dial {name!r}; known dials: {', '.join(self.names)}")

    def unreliable(self, names=None) -> list[str]:
        """The dials (of ``names``, default all) that predict an identity left out of their fit
        no better than the mean does (leave-one-out R² <= 0): a model of too few identities,
        whose dials move the face along directions that mean nothing of what they name."""
        return [d.name for d in self.dials
                if (names is None or d.name in names) and not d.r2_loo > 0.0]

    def apply(self, weights: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """Identity weights ``(..., r)`` moved by ``values`` (dial name -> units), Eq. (D2)."""
        w = np.array(weights, dtype=np.float64)
        for name, t in values.items():
            w = w + float(t) * self.get(name).direction
        return w


def measure(landmarks: np.ndarray) -> np.ndarray:
    """All :data:`MEASUREMENTS` of faces given by their 68 landmark positions.

    Parameters
    ----------
    landmarks : (..., 68, 3) float

    Returns
    -------
    (..., K) float64
    """
    L = np.asarray(landmarks, dtype=np.float64)
    if L.shape[-2:] != (68, 3):
        raise DialError(f"landmarks must be (..., 68, 3), got {L.shape}")
    return np.stack([f(L) for _, f in MEASUREMENTS.values()], axis=-1)


def neutral_weights(model, mode: str = "identity") -> dict[str, np.ndarray]:
    """Weights of every mode but ``mode``: the ``neutral`` training row if there is one, else the
    mean (the face the dials are measured on)."""
    out = {}
    for k, name in enumerate(model.mode_names):
        if name == mode:
            continue
        labs = model.labels[k]
        out[name] = (model.training_weights(k, "neutral") if "neutral" in labs
                     else model.weight_mean(k))
    return out


def identity_measurements(model, identity: np.ndarray, *, mode: str = "identity") -> np.ndarray:
    """Measurements of neutral faces with identity weights ``identity (n, r)`` -> ``(n, K)``."""
    if model.landmarks is None:
        raise DialError("identity dials need a model with landmark vertices")
    W = np.atleast_2d(np.asarray(identity, dtype=np.float64))
    w = {n: np.tile(v, (len(W), 1)) for n, v in neutral_weights(model, mode).items()}
    w[mode] = W
    L = model.synthesize(w, vertices=model.landmarks)  # (n, 68, 3), Eq. (5)
    return measure(L)


def _ridge_loo(X: np.ndarray, y: np.ndarray, lambdas: np.ndarray):
    """Ridge on centred ``X (n, r)``, ``y (n,)`` with an unpenalised intercept; the lambda of
    least leave-one-out error. Returns (b (r,), r2, r2_loo)."""
    n = len(y)
    yc = y - y.mean()
    tss = float(yc @ yc)
    K = X @ X.T
    best = None
    for lam in lambdas:
        A = np.linalg.solve(K + lam * np.eye(n), np.column_stack([yc, np.eye(n)]))
        alpha, Hc = A[:, 0], K @ A[:, 1:]
        H = Hc + 1.0 / n  # hat matrix with the intercept
        e = yc - K @ alpha
        loo = e / np.maximum(1.0 - np.diag(H), 1e-9)
        sse_loo = float(loo @ loo)
        if best is None or sse_loo < best[0]:
            best = (sse_loo, alpha, float(e @ e))
    sse_loo, alpha, sse = best
    if tss <= 0:
        return np.zeros(X.shape[1]), 0.0, 0.0
    return X.T @ alpha, 1.0 - sse / tss, 1.0 - sse_loo / tss


def learn_dials(model, *, mode: str = "identity") -> DialSet:
    """The semantic dials of ``model``, learnt from its training identities (Eq. D1, D2).

    Raises
    ------
    DialError
        The model has no such mode, fewer than 3 identities, or no landmarks.
    """
    if mode not in model.mode_names:
        raise DialError(f"the model has no {mode!r} mode (modes: {', '.join(model.mode_names)})")
    W = model.factors[model.mode_index(mode)]  # (n, r)
    if len(W) < 3:
        raise DialError(f"identity dials need at least 3 training identities, the model has "
                        f"{len(W)}")
    M = identity_measurements(model, W, mode=mode)  # (n, K)
    X = W - W.mean(axis=0)
    scale = max(float(np.trace(X.T @ X)) / max(X.shape[1], 1), 1e-12)
    lambdas = scale * np.logspace(-4, 2, 13)
    mean_w = W.mean(axis=0)
    m0 = identity_measurements(model, mean_w, mode=mode)[0]
    dials = []
    for k, (name, (desc, _)) in enumerate(MEASUREMENTS.items()):
        b, r2, r2_loo = _ridge_loo(X, M[:, k], lambdas)
        sigma = float(M[:, k].std())
        gain = float(identity_measurements(model, mean_w + b, mode=mode)[0, k] - m0[k])
        d = b * (sigma / gain) if abs(gain) > 1e-12 * max(sigma, 1e-12) else np.zeros_like(b)
        effect = float(identity_measurements(model, mean_w + d, mode=mode)[0, k] - m0[k])
        dials.append(Dial(name, desc, d, sigma, effect, float(r2), float(r2_loo)))
    ds = str(model.provenance.get("dataset", ""))
    unit = "cm" if ds.startswith("ict") else "model units"
    return DialSet(tuple(dials), mode, unit)


#: The farthest a dial is turned, in its units (standard deviations of its measurement over
#: the training identities): beyond, the face leaves the space the model was learned on
#: (``model dials`` draws -2 to +2).
DIAL_LIMIT = 5.0


def parse_dial_values(text: str, *, what: str = "--identity-dials") -> dict[str, float]:
    """``"width=+1.5,nose_length=-1"`` -> ``{"width": 1.5, "nose_length": -1.0}``; a value
    beyond :data:`DIAL_LIMIT` is refused (DialError naming it)."""
    out: dict[str, float] = {}
    for part in str(text).split(","):
        if not part.strip():
            continue
        name, sep, val = part.partition("=")
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not sep or not name.strip() or not np.isfinite(v):
            raise DialError(f"{what}: expected NAME=NUMBER[,...], got {part!r}")
        if abs(v) > DIAL_LIMIT:
            raise DialError(f"{what}: {part.strip()} is beyond the dials' range of "
                            f"-{DIAL_LIMIT:g} to +{DIAL_LIMIT:g} (standard deviations over the "
                            "training faces)")
        out[name.strip()] = v
    if not out:
        raise DialError(f"{what} is empty")
    return out


def dial_track(track, model, values: Mapping[str, float], *, dials: DialSet | None = None):
    """The track with its identity moved by the dials on every frame; landmarks re-projected.

    Parameters
    ----------
    track : Track
    model : MultilinearModel
        The track's model.
    values : dict dial name -> units
    """
    from .track.project import project_landmarks

    dials = dials or learn_dials(model)
    for name in values:
        dials.get(name)  # unknown names fail before any work
    weights = dict(track.weights)
    weights[dials.mode] = dials.apply(track.weights[dials.mode], values)
    return project_landmarks(dataclasses.replace(track, weights=weights, info={}), model)


def dial_sheet(model, dials: DialSet, *, steps=(-2.0, 0.0, 2.0), tile=(140, 170), paint=None):
    """A PIL picture: one row per dial, the mean identity at ``steps`` units, labelled with the
    dial's R² and its measured effect per unit. ``paint(V, weights, camera, tile)`` -> (H, W,
    3) uint8 draws a face (default: the mesh shaded, its eye holes and mouth gap open; ``model
    dials`` draws them as the puppet's).

    Returns
    -------
    PIL.Image.Image
    """
    from PIL import Image, ImageDraw

    from .render import look_at_weak_perspective, render, rotation_from_euler

    mode = dials.mode
    mean_w = model.weight_mean(mode)
    rest = neutral_weights(model, mode)
    faces = np.asarray(model.faces, np.int64)
    V0 = model.synthesize({**rest, mode: mean_w})
    cam = look_at_weak_perspective(V0, tile, rotation=rotation_from_euler(15.0, 0.0), fill=0.8)
    colors = np.tile(np.array([[0.85, 0.75, 0.70]]), (model.n_vertices, 1))
    lw, hh = 130, 24   # the labels: "+1 unit = +0.626 cm" is ~120 px
    W, H = tile
    img = Image.new("RGB", (lw + W * len(steps), hh + H * len(dials.dials)), "white")
    draw = ImageDraw.Draw(img)
    draw.text((4, 4), f"identity dials ({dials.unit}); columns: {', '.join(f'{t:+g}' for t in steps)}"
              " units", fill=(0, 0, 0))
    for i, d in enumerate(dials.dials):
        y = hh + i * H
        draw.text((4, y + H // 2 - 24), d.name, fill=(0, 0, 0))
        draw.text((4, y + H // 2 - 8), f"R2 {d.r2:.2f} (LOO {d.r2_loo:.2f})", fill=(60, 60, 60))
        draw.text((4, y + H // 2 + 8), f"+1 unit = {d.effect:+.3f} {dials.unit}",
                  fill=(60, 60, 60))
        for j, t in enumerate(steps):
            w = {**rest, mode: mean_w + t * d.direction}
            V = model.synthesize(w)
            rgb = render(V, faces, cam, tile, colors=colors, background=(255, 255, 255)).image \
                if paint is None else paint(V, w, cam, tile)
            img.paste(Image.fromarray(rgb), (lw + j * W, y))
    return img
