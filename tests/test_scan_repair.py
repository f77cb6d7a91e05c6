"""Raw scans that fit (issue 16, item 8): a vertex-clustered, non-manifold scan of a smiling face
is repaired (faces on non-manifold edges dropped, duplicates merged) and fitted, not refused; the
prior is chosen automatically and reported."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

#: grid cell of the vertex clustering (cm): 3 mm gives ~200 non-manifold edges on the ICT face
CLUSTER_CELL = 0.3


def smile_truth(data_dir: Path | None = None):
    """The ICT template (face area) in a smile (mouthSmile_L + mouthSmile_R): (n, 3) cm."""
    import os

    from facetransfer.correspond import load_template
    from facetransfer.io.mesh import read_obj_vertices

    root = Path(data_dir or os.environ["FACETRANSFER_DATA_DIR"]) / "ict-facekit" / "FaceXModel"
    t = load_template("ict")
    n = len(t.vertices)
    offset = sum(read_obj_vertices(root / f"{s}.obj")[:n] - t.vertices
                 for s in ("mouthSmile_L", "mouthSmile_R"))
    return t, t.vertices + offset


def clustered_smile_scan(scan_path: Path, features_path: Path, *, cell: float = CLUSTER_CELL,
                         n_points: int = 20000, seed: int = 0):
    """Write a vertex-clustered (non-manifold) smiling scan as PLY and its 68 true feature points.

    Returns (truth (n, 3), scan vertices, scan faces).
    """
    import trimesh

    from facetransfer.correspond.synthetic import cluster_vertices, make_synthetic_scan
    from facetransfer.datasets.ict import ict_template

    t, truth = smile_truth()
    uvs = ict_template("face").mesh.uvs
    s = make_synthetic_scan(truth, t.faces, uvs, t.landmarks, n_points=n_points, noise=0.0,
                            n_holes=0, transform=False, feature_noise=0.0,
                            rng=np.random.default_rng(seed))
    v, f = cluster_vertices(s.scan.vertices, s.scan.faces, cell)
    trimesh.Trimesh(v, f, process=False).export(scan_path)
    features_path.write_text(json.dumps(
        {"points": {str(i): truth[t.landmarks[i]].round(6).tolist() for i in range(17, 68)
                    if t.landmarks[i] >= 0}}))   # inner points (the jaw line is cropped)
    return truth, v, f
