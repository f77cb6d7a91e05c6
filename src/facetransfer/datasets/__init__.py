"""Face data sets (§4.1): Cartesian products of corresponded meshes as :class:`FaceDataset`.

Sources: the ICT-FaceKit builder (default, :mod:`.ict`), a manifest CSV (:mod:`.manifest`) and the
FaceWarehouse folder layout (:mod:`.facewarehouse`); :func:`load_dataset` picks one from a spec.
The product itself, one array with a mask, is :mod:`.base`; the ICT builder makes its generic
expressions identity-specific by deformation transfer (Sumner & Popović 2004,
:mod:`.deformation`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from ..errors import DatasetError
from ..lazy import lazy_names
from .base import FaceDataset

#: The other public names and the submodule of each, imported on first use (PEP 562): a model
#: load needs only :class:`FaceDataset`, and the builders bring SciPy's sparse solvers (0.1-0.2 s
#: of every command's start-up otherwise).
_LAZY = {"DeformationTransfer": "deformation", "deformation_gradients": "deformation",
         "transfer_deformation": "deformation", "triangle_frames": "deformation",
         "is_facewarehouse_dir": "facewarehouse", "read_facewarehouse": "facewarehouse",
         "ICT_DATASETS": "ict", "IctTemplate": "ict", "build_ict_dataset": "ict",
         "ict_template": "ict", "load_recipes": "ict", "read_manifest": "manifest"}


__getattr__, __dir__ = lazy_names(__name__, _LAZY)

__all__ = [
    "FaceDataset",
    "load_dataset",
    "build_ict_dataset",
    "ict_template",
    "IctTemplate",
    "load_recipes",
    "ICT_DATASETS",
    "read_manifest",
    "read_facewarehouse",
    "is_facewarehouse_dir",
    "DeformationTransfer",
    "deformation_gradients",
    "transfer_deformation",
    "triangle_frames",
]


def load_dataset(spec: str | os.PathLike, *, seed: int = 0, n_identities: int | None = None,
                 progress: Callable[[int, int], None] | None = None) -> FaceDataset:
    """A data set from a spec: ``"ict-bilinear"``, ``"ict-trilinear"``, a manifest ``.csv`` path,
    or a FaceWarehouse folder.

    Parameters
    ----------
    spec : str or path-like
    seed, n_identities
        For the ICT builders only (ignored otherwise).
    progress : callable, optional
        ``progress(done, total)``.

    Raises
    ------
    DatasetError
        If the spec is none of these.
    """
    from .facewarehouse import is_facewarehouse_dir, read_facewarehouse
    from .ict import ICT_DATASETS, build_ict_dataset
    from .manifest import read_manifest

    s = str(spec)
    if s in ICT_DATASETS:
        return build_ict_dataset(s, seed=seed, n_identities=n_identities, progress=progress)
    p = Path(s)
    if p.suffix.lower() == ".csv":
        if not p.is_file():
            raise DatasetError(f"manifest {p} does not exist")
        return read_manifest(p, progress=progress)
    if p.is_dir():
        if is_facewarehouse_dir(p):
            return read_facewarehouse(p, progress=progress)
        csvs = sorted(c.name for c in p.glob("*.csv"))
        held = f": it holds {', '.join(csvs[:3])}" + (", ..." if len(csvs) > 3 else "")
        raise DatasetError(f"folder {p} is not in the FaceWarehouse layout (Tester_N/Blendshape/"
                           "shape_K.obj); other meshes are listed in a manifest .csv (columns "
                           "path, identity, expression[, viseme])" + (held if csvs else ""))
    raise DatasetError(f"unknown data set {s!r}: expected {' or '.join(ICT_DATASETS)}, a manifest "
                       ".csv, or a FaceWarehouse folder")
