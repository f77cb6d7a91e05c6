"""FaceWarehouse layout (Cao et al. 2014): ``DIR/Tester_N/Blendshape/shape_K.obj``.

FaceWarehouse is the de-facto bilinear face data set (150 people × 47 expressions, one topology),
available to users under its own licence; it is never downloaded. Pointed at its folder, this
reads it as an identity × expression :class:`FaceDataset`. Testers and shapes are sorted by their
number; a tester lacking a shape leaves a missing cell (mask False).

References
----------
C. Cao, Y. Weng, S. Zhou, Y. Tong and K. Zhou, "FaceWarehouse: a 3D facial expression database for
visual computing", IEEE TVCG 20(3), 2014. Vlasic et al. 2005, §4.1.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import DatasetError
from .base import FaceDataset
from .manifest import dataset_from_meshes

__all__ = ["is_facewarehouse_dir", "read_facewarehouse"]

_TESTER = re.compile(r"^Tester_(\d+)$")
_SHAPE = re.compile(r"^shape_(\d+)\.obj$", re.IGNORECASE)


def _testers(root: Path) -> list[tuple[int, Path]]:
    out = []
    for d in root.iterdir():
        m = _TESTER.match(d.name)
        if m and (d / "Blendshape").is_dir():
            out.append((int(m.group(1)), d))
    return sorted(out)


def is_facewarehouse_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds at least one ``Tester_N/Blendshape`` folder."""
    p = Path(path)
    return p.is_dir() and bool(_testers(p))


def read_facewarehouse(path: str | os.PathLike, *, shapes: list[int] | None = None,
                       progress: Callable[[int, int], None] | None = None) -> FaceDataset:
    """Read a FaceWarehouse folder as an identity × expression data set.

    Parameters
    ----------
    path : path-like
        Folder holding ``Tester_N/Blendshape/shape_K.obj``.
    shapes : list of int, optional
        Only these shape numbers (default: every shape found).
    progress : callable, optional
        ``progress(done, total)`` after each mesh.

    Returns
    -------
    FaceDataset
        Modes ``("identity", "expression")``, labels ``Tester_N`` and ``shape_K``.

    Raises
    ------
    DatasetError
        Not a FaceWarehouse folder, fewer than two testers, or meshes of different vertex counts.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"FaceWarehouse folder {root} does not exist")
    testers = _testers(root)
    if not testers:
        raise DatasetError(f"{root} has no Tester_N/Blendshape folders (FaceWarehouse layout)")
    found: dict[int, dict[int, Path]] = {}
    for t, d in testers:
        for f in (d / "Blendshape").iterdir():
            m = _SHAPE.match(f.name)
            if m and (shapes is None or int(m.group(1)) in shapes):
                found.setdefault(t, {})[int(m.group(1))] = f
    all_shapes = sorted({k for s in found.values() for k in s})
    if not all_shapes:
        raise DatasetError(f"{root}: no shape_K.obj files under Tester_N/Blendshape")
    items = [(found[t][k], (f"Tester_{t}", f"shape_{k}"))
             for t, _ in testers for k in sorted(found.get(t, {}))]
    # Label order is first appearance; _reorder sorts both modes by number.
    ds = dataset_from_meshes(items, ("identity", "expression"), source=str(root), progress=progress)
    return _reorder(ds)


def _reorder(ds: FaceDataset) -> FaceDataset:
    orders = [np.argsort([int(l.split("_")[1]) for l in labs], kind="stable") for labs in ds.labels]
    v = ds.vertices[orders[0]][:, orders[1]]
    m = ds.mask[orders[0]][:, orders[1]]
    labels = tuple(tuple(labs[i] for i in o) for labs, o in zip(ds.labels, orders))
    prov = dict(ds.provenance, layout="FaceWarehouse")
    return FaceDataset(v, m, ds.mode_names, labels, ds.faces, ds.uvs, None, None, prov)
