"""ICT-FaceKit data sets: the default training data for the multilinear model (§4.1).

The ICT-FaceKit "Light" model (Li et al. 2020) has a generic neutral head, 100 identity principal
components and 53 ARKit-named expression shapes, all in one topology. It is not a Cartesian
product of real scans, so we make one (Fig. 3 of Vlasic et al. 2005):

1. identities: identity 0 is the generic neutral; identity ``i > 0`` is
   ``neutral + Σ_c w_ic (identity_c - neutral)`` with ``w_ic ~ N(0, scale²)`` drawn from
   ``numpy.random.default_rng(seed)`` (the identity files are already scaled by their standard
   deviation);
2. generic cells: each expression (and viseme) is a weighted sum of ARKit shape offsets kept in the
   readable recipe file ``facetransfer/data/ict_recipes.json``; an expression × viseme cell adds
   both offsets to the generic neutral;
3. identity-specific cells: every generic cell is carried onto every identity's neutral by
   deformation transfer (Sumner & Popović 2004), so different faces smile differently and the data
   are not trivially additive.

Built data sets are cached as ``.npz`` files in :func:`facetransfer.assets.cache_dir`, keyed by a
hash of everything that determines them, so a second build is a file read.

References
----------
Vlasic et al. 2005, §4.1 and Fig. 3; R. W. Sumner and J. Popović 2004, "Deformation transfer for
triangle meshes"; T. Li et al. 2020, "Learning formation of physically-based face attributes"
(ICT-FaceKit), https://github.com/ICT-VGL/ICT-FaceKit.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from .. import assets
from ..errors import DatasetError
from ..io.atomic import atomic_path
from ..io.memory import available_memory
from ..io.mesh import Mesh, read_obj, read_obj_vertices
from .base import FaceDataset

log = logging.getLogger(__name__)

__all__ = [
    "ICT_DATASETS",
    "REGIONS",
    "IctTemplate",
    "load_recipes",
    "ict_template",
    "build_ict_dataset",
    "ict_cache_path",
    "builder_code",
]

#: Bump when the builder's output changes for the same inputs (invalidates cached data sets).
BUILDER_VERSION = 1
#: Named vertex ranges of the FaceKit head (upstream README): the region is vertices ``0..n-1``.
REGIONS: dict[str, int] = {"face": 9409, "narrow": 6706}
#: Names accepted by :func:`build_ict_dataset`.
ICT_DATASETS = ("ict-arkit", "ict-bilinear", "ict-trilinear")
_ASSET = "ict-facekit"
_N_IDENTITY_COMPONENTS = 100

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class IctTemplate:
    """The generic ICT-FaceKit neutral restricted to a region.

    Attributes
    ----------
    mesh : Mesh
        Vertices ``(n, 3)`` (cm), triangles wholly inside the region (quads split), UVs.
        Vertex ``i`` is FaceKit vertex ``i``.
    landmarks : (68,) int64
        iBUG-68 landmark vertices (FaceKit ``idx_to_landmark_verts``).
    rigid : (m,) int64
        FaceKit rigid vertices inside the region (they move least with expression).
    region : str
    """

    mesh: Mesh
    landmarks: np.ndarray
    rigid: np.ndarray
    region: str

    @property
    def vertex_subset(self) -> np.ndarray:
        """Indices of the region's vertices in the full FaceKit mesh, ``(n,) int64``."""
        return np.arange(len(self.mesh.vertices), dtype=np.int64)


def load_recipes(path: str | Path | None = None) -> dict:
    """The recipe file (default: the packaged ``ict_recipes.json``) as a dict, validated.

    Raises
    ------
    DatasetError
        If a data set names an expression or viseme without a recipe, or a weight is not a number.
    """
    try:
        if path is None:
            text = resources.files("facetransfer.data").joinpath("ict_recipes.json").read_text()
        else:
            text = Path(path).read_text()
        rec = json.loads(text)
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetError(f"cannot read ICT recipe file {path or 'ict_recipes.json'}: {exc}") from None
    for key in ("expressions", "visemes", "datasets"):
        if not isinstance(rec.get(key), dict):
            raise DatasetError(f"ICT recipe file lacks a {key!r} table")
    _expand_arkit(rec)
    for table in ("expressions", "visemes"):
        for name, shapes in rec[table].items():
            if not isinstance(shapes, dict) or not all(
                    isinstance(w, (int, float)) and np.isfinite(w) for w in shapes.values()):
                raise DatasetError(f"recipe {table}.{name} must map shape names to numbers")
    for dname, spec in rec["datasets"].items():
        for mode, table in (("expressions", "expressions"), ("visemes", "visemes")):
            for lab in spec.get(mode, []):
                if lab not in rec[table]:
                    raise DatasetError(f"data set {dname} uses {mode[:-1]} {lab!r} with no recipe")
    return rec


def _expand_arkit(rec: dict) -> None:
    """A data set whose ``expressions`` is ``"arkit"`` gets the neutral and every ARKit shape of
    ``arkit_facekit.json`` (:mod:`facetransfer.arkit`), in :data:`~facetransfer.arkit.ARKIT_NAMES`
    order, as expression recipes."""
    from ..arkit import ARKIT_NAMES, load_facekit_mapping

    for spec in rec["datasets"].values():
        if spec.get("expressions") != "arkit":
            continue
        shapes = load_facekit_mapping()["shapes"]
        names = [n for n in ARKIT_NAMES if n in shapes]
        rec["expressions"].setdefault("neutral", {})
        for n in names:
            rec["expressions"][n] = dict(shapes[n])
        spec["expressions"] = ["neutral"] + names


def _load_landmarks_and_rigid(n: int) -> tuple[np.ndarray, np.ndarray]:
    path = assets.asset_file(_ASSET, "vertex_indices.json")
    try:
        j = json.loads(Path(path).read_text())
        lm = np.asarray(j["idx_to_landmark_verts"], dtype=np.int64)
        rigid = np.asarray(j["idx_to_rigid_verts"], dtype=np.int64)
    except (OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"cannot read landmarks from {path}: {exc}") from None
    if lm.shape != (68,):
        raise DatasetError(f"{path}: expected 68 landmark vertices, got {lm.shape}")
    if lm.min() < 0 or lm.max() >= n:
        raise DatasetError(f"{path}: landmark vertices outside the region 0..{n - 1}")
    return lm, rigid[(rigid >= 0) & (rigid < n)]


def ict_template(region: str = "face") -> IctTemplate:
    """The ICT-FaceKit generic neutral restricted to a region, with its 68 landmarks.

    Parameters
    ----------
    region : {"face", "narrow"}
        ``"face"``: FaceKit vertices 0..9408 (full face area); ``"narrow"``: 0..6705.

    Returns
    -------
    IctTemplate
        Vertex ``i`` of the template is FaceKit vertex ``i``; triangles wholly inside the region.
    """
    if region not in REGIONS:
        raise DatasetError(f"unknown ICT region {region!r}; expected one of {sorted(REGIONS)}")
    n = REGIONS[region]
    full = read_obj(assets.asset_file(_ASSET, "generic_neutral_mesh.obj"))
    faces = full.faces[(full.faces < n).all(axis=1)]
    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    if not used.all():
        raise DatasetError(f"ICT region {region!r}: {int((~used).sum())} vertices in no triangle")
    uvs = None if full.uvs is None else full.uvs[:n].copy()
    lm, rigid = _load_landmarks_and_rigid(n)
    return IctTemplate(Mesh(full.vertices[:n].copy(), faces, uvs), lm, rigid, region)


def _dataset_spec(name: str, recipes: Mapping) -> dict:
    if name not in recipes["datasets"]:
        raise DatasetError(f"unknown ICT data set {name!r}; expected one of "
                           f"{sorted(recipes['datasets'])}")
    return recipes["datasets"][name]


def _used_recipes(spec: Mapping, recipes: Mapping) -> dict:
    return {"expressions": {e: recipes["expressions"][e] for e in spec["expressions"]},
            "visemes": {v: recipes["visemes"][v] for v in spec.get("visemes", [])}}


@functools.lru_cache(maxsize=1)
def builder_code() -> str:
    """A digest of the code (and data files) this builder can run
    (:func:`facetransfer.code_digest.closure_digest` of this module): in every cached file's
    key, so that a changed builder never reads a data set or components an older one made
    (before, only :data:`BUILDER_VERSION`, bumped by hand, and the asset's commit were)."""
    from .. import code_digest

    return code_digest.closure_digest([__name__], "", root=code_digest.PACKAGE_ROOT)


def _cache_key(name: str, seed: int, n_identities: int, region: str, used: Mapping,
               identity: Mapping) -> str:
    blob = json.dumps({"name": name, "seed": seed, "n_identities": n_identities,
                       "region": region, "recipes": used, "identity": identity,
                       "builder": BUILDER_VERSION, "commit": assets.ICT_COMMIT,
                       "code": builder_code()},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def ict_cache_path(name: str, *, seed: int = 0, n_identities: int | None = None,
                   region: str = "face", recipes: Mapping | None = None) -> Path:
    """Where :func:`build_ict_dataset` caches this data set (the file may not exist yet)."""
    rec = load_recipes() if recipes is None else recipes
    spec = _dataset_spec(name, rec)
    n_id = int(spec["n_identities"] if n_identities is None else n_identities)
    key = _cache_key(name, int(seed), n_id, region, _used_recipes(spec, rec), rec.get("identity", {}))
    return assets.cache_dir() / "datasets" / f"{name}-{region}-n{n_id}-s{seed}-{key}.npz"


def _read_prefix_vertices(path: Path, n: int) -> np.ndarray:
    """The first ``n`` vertices of an OBJ whose ``v`` lines are contiguous (as in the FaceKit).

    About 5x faster than parsing every line; falls back to
    :func:`facetransfer.io.mesh.read_obj_vertices` for any other layout.
    """
    with open(path, "rb") as fh:
        data = fh.read()
    start = 0 if data.startswith(b"v ") else data.find(b"\nv ") + 1
    lines = data[start:].split(b"\n", n)[:n] if start > 0 or data.startswith(b"v ") else []
    if len(lines) == n and all(ln[:2] == b"v " for ln in lines):
        vals = np.array(b" ".join(ln[2:] for ln in lines).split(), dtype=np.float64)
        if vals.size == 3 * n and np.all(np.isfinite(vals)):
            return vals.reshape(n, 3)
    v = read_obj_vertices(path)
    if len(v) < n:
        raise DatasetError(f"{path} has {len(v)} vertices, fewer than the region's {n}")
    return v[:n]


def _cached_offsets(stem: str, key: str, shape: tuple[int, ...],
                    build: Callable[[], np.ndarray], use_cache: bool) -> np.ndarray:
    """Shape offsets ``shape`` read from the ``.npy`` cache file ``stem + key + ".npy"`` if it
    is there and sound, else ``build()`` (then saved atomically when ``use_cache``, and the
    files of ``stem`` under other keys pruned: :func:`_prune_others`)."""
    cache = assets.cache_dir() / "datasets" / f"{stem}{key}.npy"
    if use_cache and cache.is_file():
        try:
            comps = np.load(cache, allow_pickle=False)
            if comps.shape == shape and np.all(np.isfinite(comps)):
                return comps
        except (OSError, ValueError) as exc:
            log.warning("ignoring unreadable %s (%s)", cache, exc)
    comps = build()
    if use_cache:
        cache.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cache) as tmp:
            np.save(tmp, comps)
        _prune_others(cache, stem)
    return comps


#: Cached files of one data set (or components) under other keys kept beside the current one:
#: made by another builder's code or recipe, read again only by a switch back to it.
KEEP_OTHERS = 2


def _prune_others(path: Path, stem: str) -> None:
    """Remove the files of ``path``'s folder whose names begin with ``stem`` (the same data set
    or components under other keys) but ``path`` and the :data:`KEEP_OTHERS` most recent: a
    change of the builder's code or recipes makes new keys (:func:`builder_code`), and each
    stale ``ict-arkit`` data set is 0.6 GB."""
    from ..assets import prune_beside

    prune_beside(path, f"{stem}*", KEEP_OTHERS, "another key of a cached data set")


def _identity_components(neutral: np.ndarray, region: str, use_cache: bool) -> np.ndarray:
    """The 100 identity offsets ``identity_c - neutral`` over the region, ``(100, n, 3)``.

    Cached as ``.npy`` (keyed by asset commit and region) because parsing 100 OBJ files dominates
    small builds.
    """
    n = len(neutral)

    def build():
        return np.stack([_read_prefix_vertices(assets.asset_file(_ASSET, f"identity{c:03d}.obj"), n)
                         for c in range(_N_IDENTITY_COMPONENTS)]) - neutral

    return _cached_offsets(
        f"ict-identity-components-{region}-",
        f"{assets.ICT_COMMIT[:12]}-v{BUILDER_VERSION}-{builder_code()[:8]}",
        (_N_IDENTITY_COMPONENTS, n, 3), build, use_cache)


def ict_expression_names() -> tuple[str, ...]:
    """The FaceKit's ARKit-named expression shapes (sorted), from the asset registry.

    Every ``*.obj`` of the asset except the identities, the generic neutral and the pupil
    dilation shapes (which move only the eyeballs, outside the face area).
    """
    rels = [f.relpath for f in assets._get(_ASSET).files]
    return tuple(sorted(r[:-4] for r in rels if r.endswith(".obj")
                        and not r.startswith(("identity", "generic_neutral", "PupilDilate"))))


def ict_expression_components(region: str = "face", use_cache: bool = True, *,
                              neutral: np.ndarray | None = None
                              ) -> tuple[tuple[str, ...], np.ndarray]:
    """Names and offsets ``shape - neutral`` ``(E, n, 3)`` of the expression shapes over a region.

    Cached as ``.npy`` like the identity components. ``neutral``: the region's generic neutral,
    if already read.
    """
    names = ict_expression_names()
    if neutral is None:
        neutral = ict_template(region).mesh.vertices
    tag = hashlib.sha256("\n".join(names).encode()).hexdigest()[:8]

    def build():
        off = _offsets(set(names), neutral)
        return np.stack([off[k] for k in names])

    comps = _cached_offsets(
        f"ict-expression-components-{region}-",
        f"{assets.ICT_COMMIT[:12]}-{tag}-v{BUILDER_VERSION}-{builder_code()[:8]}",
        (len(names), len(neutral), 3), build, use_cache)
    return names, comps


def ict_identity_components(region: str = "face", use_cache: bool = True, *,
                            neutral: np.ndarray | None = None) -> np.ndarray:
    """ICT-FaceKit's 100 identity offsets ``(100, n, 3)`` over a region (scaled by their std)."""
    if neutral is None:
        neutral = ict_template(region).mesh.vertices
    return _identity_components(neutral, region, use_cache)


def _offsets(names: set[str], neutral: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for s in sorted(names):
        try:
            path = assets.asset_file(_ASSET, f"{s}.obj")
        except Exception as exc:  # unknown shape name -> clear error
            raise DatasetError(f"recipe uses unknown ICT shape {s!r}: {exc}") from None
        out[s] = _read_prefix_vertices(path, len(neutral)) - neutral
    return out


def _combine(recipe: Mapping[str, float], offsets: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    d = np.zeros((n, 3))
    for s, w in recipe.items():
        d += float(w) * offsets[s]
    return d


def _save_cache(path: Path, ds: FaceDataset) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.savez(tmp, vertices=ds.vertices, mask=ds.mask, faces=ds.faces,
                 uvs=ds.uvs if ds.uvs is not None else np.zeros((0, 2)),
                 landmarks=ds.landmarks, vertex_subset=ds.vertex_subset,
                 meta=np.array(json.dumps({"mode_names": ds.mode_names,
                                           "labels": ds.labels,
                                           "provenance": ds.provenance})))


def _reproducible(provenance: Mapping) -> dict:
    """``provenance`` without the build's duration, which caches written before the fifty-first
    session hold: in a model's metadata it changed the content hash of every build of the same
    data set (the default model's tracks and face files were refused after a rebuild)."""
    return {k: v for k, v in provenance.items() if k != "build_seconds"}


def _load_cache(path: Path) -> FaceDataset | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            uvs = z["uvs"]
            return FaceDataset(
                z["vertices"], z["mask"], tuple(meta["mode_names"]),
                tuple(tuple(l) for l in meta["labels"]), z["faces"],
                uvs if len(uvs) else None, z["landmarks"], z["vertex_subset"],
                _reproducible(meta["provenance"]))
    except Exception as exc:  # a damaged cache file is rebuilt, never trusted
        log.warning("ignoring unreadable cached data set %s (%s)", path, exc)
        return None


def build_memory_bytes(n_identities: int, n_cells: int, n_vertices: int) -> int:
    """Peak memory of building a data set and its model, estimated (bytes).

    The data tensor ``(n_identities, n_cells, n, 3)`` float64 is held about four times at the
    peak (the cells, the tensor handed to the N-mode SVD, its unfolding and the core), plus the
    100 identity components.
    """
    tensor = 8 * 3 * n_vertices * n_identities * n_cells
    return int(4 * tensor + 8 * 3 * n_vertices * (_N_IDENTITY_COMPONENTS + n_cells))


#: the memory available, a container's limit included (a name of this module: tests replace it)
_available_bytes = available_memory


def check_build_memory(name: str, n_identities: int, spec: Mapping, region: str) -> None:
    """Refuse, before allocating, a build that would not fit in the available memory."""
    cells = len(spec["expressions"]) * max(1, len(spec.get("visemes", [])))
    need = build_memory_bytes(n_identities, cells, REGIONS[region])
    avail = _available_bytes()
    if avail is not None and need > avail:
        raise DatasetError(f"{name} with {n_identities} identities needs about "
                           f"{need / 2**30:.1f} GiB of memory; {avail / 2**30:.1f} GiB is "
                           f"available (use fewer --identities)")


def build_ict_dataset(name: str, *, seed: int = 0, n_identities: int | None = None,
                      region: str = "face", progress: Progress | None = None,
                      use_cache: bool = True, recipes: Mapping | None = None) -> FaceDataset:
    """Build (or read from the cache) an ICT-FaceKit data set.

    Parameters
    ----------
    name : {"ict-arkit", "ict-bilinear", "ict-trilinear"}
        ``ict-bilinear``: identity × expression (15 × 10 by default); ``ict-trilinear``:
        identity × expression × viseme (16 × 5 × 5), as the paper's two models (§4.3);
        ``ict-arkit``: identity × (neutral + 51 ARKit blendshapes), 50 identities by default,
        the default model (:mod:`facetransfer.arkit`, ``data/arkit_facekit.json``).
    seed : int
        Seed of the identity weights.
    n_identities : int, optional
        Number of identities including the generic one (default from the recipe file); at least 2.
    region : {"face", "narrow"}
        Vertex region (:func:`ict_template`).
    progress : callable, optional
        Called as ``progress(done, total)`` after each identity.
    use_cache : bool
        Read and write the ``.npz`` cache (:func:`ict_cache_path`).
    recipes : dict, optional
        Recipe table (default the packaged ``ict_recipes.json``).

    Returns
    -------
    FaceDataset
        ``vertices (n_identities, n_expressions[, n_visemes], n, 3)``, full mask, labels,
        triangles, UVs, 68 landmarks, ``vertex_subset = arange(n)``, and provenance (recipes,
        seed, identity weights, asset commit; no timing, so that building it again gives a model
        of the same content hash: its arrays are the same bits; the seconds go to the log).

    References
    ----------
    Vlasic et al. 2005, §4.1; Sumner & Popović 2004.
    """
    rec = load_recipes() if recipes is None else recipes
    spec = _dataset_spec(name, rec)
    n_id = int(spec["n_identities"] if n_identities is None else n_identities)
    if n_id < 2:
        raise DatasetError(f"n_identities must be at least 2, got {n_id}")
    if region not in REGIONS:
        raise DatasetError(f"unknown ICT region {region!r}; expected one of {sorted(REGIONS)}")
    check_build_memory(name, n_id, spec, region)
    cache = ict_cache_path(name, seed=seed, n_identities=n_id, region=region, recipes=rec)
    if use_cache and cache.is_file():
        ds = _load_cache(cache)
        if ds is not None:
            log.info("read cached %s from %s", name, cache)
            return ds

    ds = _build(name, spec, rec, seed=seed, n_id=n_id, region=region, progress=progress,
                use_cache=use_cache)
    if use_cache:
        _save_cache(cache, ds)
        _prune_others(cache, cache.name[:-len(cache.name.rsplit("-", 1)[1])])
    return ds


def _build(name: str, spec: dict, rec: Mapping, *, seed: int, n_id: int, region: str,
           progress: Progress | None, use_cache: bool) -> FaceDataset:
    """Steps 1-3 of the module docstring for one data set spec; the provenance records them."""
    t0 = time.perf_counter()
    used = _used_recipes(spec, rec)
    id_cfg = rec.get("identity", {})
    scale = float(id_cfg.get("scale", 1.0))
    include_generic = bool(id_cfg.get("include_generic", True))
    tmpl = ict_template(region)
    faces, n = tmpl.mesh.faces, len(tmpl.mesh.vertices)
    neutral = tmpl.mesh.vertices
    w = _identity_weights(seed, n_id, scale, include_generic)
    id_neutral = _identity_neutrals(neutral, region, w, use_cache)  # step 1
    off = _offsets(_used_shapes(used), neutral)
    cell_off = _generic_cell_offsets(used, spec, off, n)  # step 2
    anchors = _anchor_vertices(tmpl, off, n)
    out = _transfer_cells(neutral, cell_off, faces, anchors, id_neutral, progress)  # step 3
    seconds = time.perf_counter() - t0
    modes, labels = _modes_and_labels(spec, n_id, include_generic)
    prov = {
        "dataset": name, "builder": "facetransfer.datasets.ict", "builder_version": BUILDER_VERSION,
        "seed": int(seed), "n_identities": n_id, "region": region,
        "recipes": used, "identity_scale": scale, "identity_weights": w.round(12).tolist(),
        "anchors": anchors.tolist(),
        "asset": assets.describe(_ASSET) | {"commit": assets.ICT_COMMIT},
        "default_ranks": spec.get("default_ranks", {}),
    }
    ds = FaceDataset(out, np.ones(out.shape[:-2], dtype=bool), modes, labels, faces,
                     tmpl.mesh.uvs, tmpl.landmarks, tmpl.vertex_subset, prov)
    log.info("built %s (%s cells, %d vertices) in %.1f s", name, out.shape[:-2], n, seconds)
    return ds


def _identity_weights(seed: int, n_id: int, scale: float, include_generic: bool) -> np.ndarray:
    """Seeded identity weights ``(n_id, 100)``; row 0 zero (the generic face) if included."""
    rng = np.random.default_rng(seed)
    w = scale * rng.standard_normal((n_id, _N_IDENTITY_COMPONENTS))
    if include_generic:
        w[0] = 0.0
    return w


def _identity_neutrals(neutral: np.ndarray, region: str, w: np.ndarray, use_cache: bool
                       ) -> np.ndarray:
    """Step 1: every identity's neutral face, ``neutral + Σ w_k c_k``, shape (n_id, n, 3)."""
    comps = _identity_components(neutral, region, use_cache)  # (100, n, 3)
    return neutral + np.tensordot(w, comps, axes=1)  # (n_id, n, 3)


def _used_shapes(used: dict) -> set:
    """Names of every ICT blendshape the used expression and viseme recipes combine."""
    shapes = {s for r in used["expressions"].values() for s in r}
    return shapes | {s for r in used["visemes"].values() for s in r}


def _generic_cell_offsets(used: dict, spec: dict, off: dict, n: int) -> np.ndarray:
    """Step 2: the generic face's offset of every cell, expression offset [+ viseme offset].

    Returns
    -------
    (E, n, 3) or (E, V, n, 3) float64
    """
    expr = [_combine(used["expressions"][e], off, n) for e in spec["expressions"]]
    vis = [_combine(used["visemes"][v], off, n) for v in spec.get("visemes", [])]
    if vis:
        return np.stack([[e + v for v in vis] for e in expr])  # (E, V, n, 3)
    return np.stack(expr)  # (E, n, 3)


def _anchor_vertices(tmpl, off: dict, n: int) -> np.ndarray:
    """Anchors of the deformation transfer: per component, the rigid vertex that moves least
    over all used shapes."""
    motion = sum(np.linalg.norm(o, axis=1) for o in off.values()) if off else np.zeros(n)
    preferred = tmpl.rigid[np.argsort(motion[tmpl.rigid], kind="stable")]
    from .deformation import component_anchors

    return component_anchors(n, tmpl.mesh.faces, preferred)


def _transfer_cells(neutral: np.ndarray, cell_off: np.ndarray, faces: np.ndarray,
                    anchors: np.ndarray, id_neutral: np.ndarray,
                    progress: Progress | None) -> np.ndarray:
    """Step 3: deformation transfer of every generic cell onto every identity (Sumner & Popović
    2004), shape (n_id, *cells, n, 3)."""
    from .deformation import DeformationTransfer, deformation_gradients  # SciPy's solvers

    n_id, n = id_neutral.shape[0], neutral.shape[0]
    Q = deformation_gradients(neutral, neutral + cell_off, faces)  # (*cells, F, 3, 3)
    out = np.empty((n_id,) + cell_off.shape[:-2] + (n, 3))
    for i in range(n_id):
        dt = DeformationTransfer(id_neutral[i], faces, anchors)
        P = id_neutral[i][dt.fixed] + cell_off[..., dt.fixed, :]
        out[i] = dt.solve(Q, P)
        if progress is not None:
            progress(i + 1, n_id)
    return out


def _modes_and_labels(spec: dict, n_id: int, include_generic: bool
                      ) -> tuple[tuple[str, ...], tuple[tuple[str, ...], ...]]:
    """Mode names and labels: ``generic``/``idNN`` identities, the expressions[, the visemes]."""
    width = max(2, len(str(n_id - 1)))
    id_labels = tuple(("generic" if (i == 0 and include_generic) else f"id{i:0{width}d}")
                      for i in range(n_id))
    labels = (id_labels, tuple(spec["expressions"]))
    modes: tuple[str, ...] = ("identity", "expression")
    if spec.get("visemes", []):
        labels = labels + (tuple(spec["visemes"]),)
        modes = modes + ("viseme",)
    return modes, labels
