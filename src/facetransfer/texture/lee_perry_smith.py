"""The Lee Perry-Smith head scan as the default face texture (issue 5).

The scan (Infinite Realities, CC-BY 3.0; credit :data:`LEE_PERRY_SMITH_CREDIT` wherever it is
shown) is loaded from the asset registry (:func:`load_lee_perry_smith`); its colour map is carried
onto a fitted template's UVs by closest points (:func:`lee_perry_smith_texture`,
:func:`facetransfer.texture.bake.bake_texture`), and once for the ICT-FaceKit template after
detecting feature points on a rendering of the scan and fitting the template to it (§4.2,
:func:`lee_perry_smith_template_texture`). Results are cached in the user cache.
"""

from __future__ import annotations

import hashlib
import logging

import cv2
import numpy as np

from ..io.atomic import atomic_path, write_image
from .bake import bake_texture
from .base import TextureError, check_uvs, check_vertices

log = logging.getLogger(__name__)

__all__ = ["LEE_PERRY_SMITH_CREDIT", "load_lee_perry_smith", "lee_perry_smith_texture",
           "lee_perry_smith_template_texture"]

#: Credit line to show wherever the Lee Perry-Smith head texture is shown (CC-BY 3.0).
LEE_PERRY_SMITH_CREDIT = "Lee Perry-Smith (Infinite Realities), CC-BY 3.0"


def load_lee_perry_smith():
    """The Lee Perry-Smith head scan and its colour map (credit :data:`LEE_PERRY_SMITH_CREDIT`).

    Returns
    -------
    mesh : Mesh
        9,279 vertices, 17,684 triangles, y up, facing +z; ``uvs`` converted to v up (the glTF
        file stores v down).
    image : (1024, 1024, 3) uint8 RGB
        ``Map-COL.jpg``.

    Raises
    ------
    AssetError
        The asset is missing (offline, no mirror) or fails its checksum.
    """
    from ..assets import asset_path
    from ..errors import AssetError
    from ..io.mesh import Mesh, read_mesh

    root = asset_path("lee-perry-smith")
    mesh = read_mesh(root / "LeePerrySmith.glb")
    if mesh.uvs is None:
        raise AssetError(f"{root / 'LeePerrySmith.glb'} has no texture coordinates")
    uvs = mesh.uvs.copy()
    uvs[:, 1] = 1.0 - uvs[:, 1]  # glTF: v down -> v up
    img = cv2.imread(str(root / "Map-COL.jpg"), cv2.IMREAD_COLOR)
    if img is None:
        raise AssetError(f"{root / 'Map-COL.jpg'} is not an image OpenCV can read")
    return Mesh(mesh.vertices, mesh.faces, uvs), cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def lee_perry_smith_texture(fitted_vertices, faces, uvs, size: int = 512, *,
                            source_samples: int = 1024, use_cache: bool = True) -> np.ndarray:
    """The Lee Perry-Smith colour map carried onto a template's UVs (issue 5 default texture).

    Parameters
    ----------
    fitted_vertices : (n, 3) float64
        The template fitted to the Lee Perry-Smith scan, in the scan's coordinates
        (template fitting, §4.1–4.2).
    faces : (F, 3) int64
        The template's triangles.
    uvs : (n, 2) float64
        The template's UVs (v up).
    size : int
    source_samples : int, keyword-only
        Side of the scan's sampling atlas (:func:`bake_texture`); 1024 matches its colour map.
    use_cache : bool, keyword-only
        Reuse / store the result in the user cache (``cache_dir()/textures``), keyed by the
        inputs' content.

    Returns
    -------
    (size, size, 3) uint8
        Show it with the credit :data:`LEE_PERRY_SMITH_CREDIT`.
    """
    from ..assets import cache_dir

    V, F = check_vertices(fitted_vertices, faces)
    U = check_uvs(uvs, V.shape[0])
    key = _content_key((V, F, U), f"lps-v1-{int(size)}-{int(source_samples)}")
    path = cache_dir() / "textures" / f"lee-perry-smith-{key}-{int(size)}.png"
    cached = _read_cached_image(path, int(size)) if use_cache else None
    if cached is not None:
        return cached
    mesh, image = load_lee_perry_smith()
    tex = bake_texture(V, F, U, mesh.vertices, mesh.faces, mesh.uvs, image, size,
                       source_samples=source_samples).texture
    if use_cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_image(path, tex)
        log.info("cached the Lee Perry-Smith texture at %s", path)
    return tex


def _content_key(arrays, tag: str) -> str:
    """16 hex digits of the SHA-256 of the arrays' bytes and ``tag``: a cache key."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(tag.encode())
    return h.hexdigest()[:16]


def _read_cached_image(path, T: int) -> np.ndarray | None:
    """A cached ``(T, T, 3) uint8`` RGB texture, or None if missing, unreadable or not T x T."""
    if not path.is_file():
        return None
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is not None and img.shape == (T, T, 3):
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return None


#: Bump when the Lee Perry-Smith template pipeline changes (invalidates cached results).
_LPS_PIPELINE_VERSION = 2
#: iBUG-68 points detected on the rendered scan and used as fitting features (no jaw contour).
_LPS_FEATURES = tuple(range(17, 68))


def uses_ict_uvs(model_or_uvs) -> bool:
    """True if the mesh's UVs are those of ICT-FaceKit vertices (``vertex_subset`` or 0..n-1)."""
    from ..datasets.ict import ict_template

    U = model_or_uvs if isinstance(model_or_uvs, np.ndarray) else getattr(model_or_uvs, "uvs", None)
    if U is None:
        return False
    U = np.asarray(U, dtype=np.float64)
    sub = None if isinstance(model_or_uvs, np.ndarray) else getattr(model_or_uvs, "vertex_subset", None)
    ict_uvs = ict_template("face").mesh.uvs
    sub = np.arange(U.shape[0]) if sub is None else np.asarray(sub, dtype=np.int64)
    if U.ndim != 2 or sub.shape != (U.shape[0],) or sub.size == 0 or sub.max() >= len(ict_uvs) \
            or sub.min() < 0:
        return False
    return bool(np.allclose(U, ict_uvs[sub], atol=1e-6))


def _lps_features(mesh, image, *, size: int = 640):
    """iBUG feature points on the Lee Perry-Smith scan: detected on a frontal rendering.

    The scan is rendered frontally with its colour map, MediaPipe's face landmarker finds the
    478 points (mapped to iBUG-68), and each point is lifted back onto the scan surface through
    the z-buffer (:func:`facetransfer.correspond.detect.detect_scan_features`).
    """
    from ..correspond.detect import FeatureDetectionError, detect_scan_features

    V = mesh.vertices
    head = V[V[:, 1] > np.percentile(V[:, 1], 20)]  # the bust's head, not the shoulders
    try:
        return detect_scan_features(V, mesh.faces, uvs=mesh.uvs, texture=image, view="front",
                                    ids=_LPS_FEATURES, size=size, fill=0.9,
                                    frame_vertices=head).features
    except FeatureDetectionError:
        raise TextureError("no face found on the rendered Lee Perry-Smith scan") from None


def lee_perry_smith_template_texture(size: int = 512, *, use_cache: bool = True) -> np.ndarray:
    """The Lee Perry-Smith scan's colour map on the ICT-FaceKit template's UVs (issue 5).

    Pipeline (run once, then cached in the user cache, ``cache_dir()/textures``):

    1. feature points on the scan: iBUG-68 brows, nose, eyes and lips detected by MediaPipe on a
       frontal rendering and lifted onto the surface (:func:`_lps_features`);
    2. template fitting (§4.2, :func:`facetransfer.correspond.fitting.fit_template`) of the
       ICT-FaceKit face area to the scan;
    3. closest-point transfer of the colour map to the template's UVs (:func:`bake_texture`).

    The image applies to every mesh whose UVs are ICT-FaceKit's (the ICT data sets and the
    models built from them). Credit :data:`LEE_PERRY_SMITH_CREDIT` wherever it is shown.

    Parameters
    ----------
    size : int
        Texture width and height.
    use_cache : bool, keyword-only

    Returns
    -------
    (size, size, 3) uint8 RGB

    Raises
    ------
    AssetError
        The ICT-FaceKit, Lee Perry-Smith or MediaPipe assets are missing.
    TextureError, FitDivergedError
        No face detected on the scan, or the fit failed.
    """
    from ..assets import cache_dir
    from ..datasets.ict import ict_template

    T = int(size)
    if T != size or T < 8 or T > 8192:
        raise TextureError(f"size must be an integer in 8..8192, got {size!r}")
    tmpl = ict_template("face")
    key = _content_key((tmpl.mesh.vertices, tmpl.mesh.faces, tmpl.mesh.uvs, tmpl.landmarks),
                       f"lps-ict-v{_LPS_PIPELINE_VERSION}")
    folder = cache_dir() / "textures"
    tex_path = folder / f"lee-perry-smith-ict-face-{key}-{T}.png"
    fit_path = folder / f"lee-perry-smith-ict-face-{key}-fit.npy"
    cached = _read_cached_image(tex_path, T) if use_cache else None
    if cached is not None:
        return cached
    fitted = _read_cached_fit(fit_path, tmpl.mesh.vertices.shape) if use_cache else None
    if fitted is None:
        fitted = _fit_ict_to_lee_perry_smith()
        if use_cache:
            folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(fit_path) as tmp:
                np.save(tmp, fitted)
    tex = lee_perry_smith_texture(fitted, tmpl.mesh.faces, tmpl.mesh.uvs, T, use_cache=False)
    if use_cache:
        folder.mkdir(parents=True, exist_ok=True)
        write_image(tex_path, tex)
    return tex


def _read_cached_fit(path, shape: tuple) -> np.ndarray | None:
    """A cached template fit of that ``shape`` (n, 3), or None if missing, unreadable or other."""
    if not path.is_file():
        return None
    try:
        fitted = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        return None
    return fitted if fitted.shape == shape else None


def _fit_ict_to_lee_perry_smith() -> np.ndarray:
    """The ICT-FaceKit template (with its identity prior) fitted to the Lee Perry-Smith scan
    (§4.2) from feature points detected on it: ``(n, 3)`` in the scan's coordinates."""
    from ..correspond.fitting import fit_template, load_template
    from ..correspond.meshops import clean_scan

    mesh, image = load_lee_perry_smith()
    features = _lps_features(mesh, image)
    scan = clean_scan(mesh.vertices, mesh.faces, name="LeePerrySmith.glb")
    fit = fit_template(scan, features, load_template("ict"))   # with the identity prior
    log.info("fitted the ICT template to the Lee Perry-Smith scan: %s", fit.stats)
    return fit.vertices
