"""Data sets from a manifest CSV of corresponded meshes (§4.1, Fig. 3).

A manifest lists one mesh per row with its attribute values::

    path,identity,expression[,viseme]
    alice/neutral.obj,alice,neutral
    alice/smile.ply,alice,smile
    ...

Paths are relative to the CSV's folder (absolute paths are kept). Every mesh must have the same
number of vertices, in corresponding order (any format :func:`facetransfer.io.mesh.read_mesh`
reads). Cells not listed are *missing*: their mask entry is False and their vertices NaN (§4.4
fills them). Labels keep the order of first appearance.
"""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import DatasetError, MeshError
from ..io.mesh import read_mesh, read_obj_vertices
from .base import FaceDataset

log = logging.getLogger(__name__)

__all__ = ["read_manifest", "dataset_from_meshes", "MANIFEST_MODES"]

#: Columns a manifest may have, in mode order; ``path``, ``identity`` and ``expression`` are required.
MANIFEST_MODES = ("identity", "expression", "viseme")


def read_manifest(path: str | os.PathLike, *,
                  progress: Callable[[int, int], None] | None = None) -> FaceDataset:
    """Read a manifest CSV into a :class:`FaceDataset` (missing cells masked and NaN).

    Parameters
    ----------
    path : path-like
        CSV with header ``path, identity, expression[, viseme]`` (whitespace around names and
        values is ignored).
    progress : callable, optional
        ``progress(done, total)`` after each mesh.

    Returns
    -------
    FaceDataset
        Triangles and UVs from the first mesh; ``provenance["missing"]`` lists missing cells.

    Raises
    ------
    DatasetError
        Unknown or missing column, empty manifest, duplicate cell, fewer than two identities,
        a mesh whose vertex count differs from the first (file and both counts named).
    MeshError
        Unreadable, empty, or non-finite mesh file (file named).
    """
    p = Path(path)
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise DatasetError(f"cannot read manifest {p}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(f"manifest {p} is not a readable CSV: {exc}") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise DatasetError(f"manifest {p} is empty")
    header = [h.strip().lower() for h in rows[0]]
    if header[:2] == ["timecode", "blendshapecount"]:   # before: its 63 columns listed
        raise DatasetError(f"{p} is a Live Link Face take (its header starts Timecode,"
                           "BlendShapeCount), not a manifest of meshes: expected the columns "
                           "path, identity, expression[, viseme]")
    unknown = [h for h in header if h not in ("path",) + MANIFEST_MODES]
    if unknown:
        raise DatasetError(f"manifest {p}: unknown column(s) {unknown}; expected "
                           f"path, identity, expression[, viseme]")
    for req in ("path", "identity", "expression"):
        if req not in header:
            raise DatasetError(f"manifest {p}: missing column {req!r}")
    if len(set(header)) != len(header):
        raise DatasetError(f"manifest {p}: repeated column in header {header}")
    modes = tuple(m for m in MANIFEST_MODES if m in header)
    col = {h: i for i, h in enumerate(header)}
    entries: list[tuple[Path, tuple[str, ...], int]] = []
    for lineno, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise DatasetError(f"manifest {p} line {lineno}: {len(r)} fields, expected {len(header)}")
        vals = tuple(r[col[m]].strip() for m in modes)
        if any(not v for v in vals) or not r[col["path"]].strip():
            raise DatasetError(f"manifest {p} line {lineno}: empty field")
        mp = Path(r[col["path"]].strip())
        entries.append((mp if mp.is_absolute() else p.parent / mp, vals, lineno))
    if not entries:
        raise DatasetError(f"manifest {p} lists no meshes")
    return dataset_from_meshes([(e[0], e[1]) for e in entries], modes, source=str(p),
                               progress=progress, lines=[e[2] for e in entries])


def _read_vertices(path: Path) -> np.ndarray:
    """Vertices only (fast for OBJ: no face parsing), with the same checks as ``read_mesh``."""
    if path.suffix.lower() != ".obj":
        return read_mesh(path).vertices
    if not path.is_file():
        raise MeshError(f"mesh file {path} does not exist")
    if path.stat().st_size == 0:
        raise MeshError(f"mesh file {path} is empty")
    return read_obj_vertices(path)


def dataset_from_meshes(items: list[tuple[Path, tuple[str, ...]]], modes: tuple[str, ...], *,
                        source: str = "", progress: Callable[[int, int], None] | None = None,
                        lines: list[int] | None = None) -> FaceDataset:
    """Arrange meshes with attribute labels into a :class:`FaceDataset`.

    Parameters
    ----------
    items : list of (path, labels)
        One mesh file per cell, ``labels`` one per mode.
    modes : tuple of str
        Mode names (first: identity).
    source : str
        Where the list came from, for messages and provenance.

    Returns
    -------
    FaceDataset
    """
    labels: list[list[str]] = [[] for _ in modes]
    index: dict[tuple[str, ...], Path] = {}
    for k, (path, vals) in enumerate(items):
        if len(vals) != len(modes):
            raise DatasetError(f"{source}: {path} has {len(vals)} labels for modes {modes}")
        if vals in index:
            where = f" line {lines[k]}" if lines else ""
            raise DatasetError(f"{source}{where}: duplicate cell {dict(zip(modes, vals))} "
                               f"({index[vals]} and {path})")
        index[vals] = Path(path)
        for m, v in enumerate(vals):
            if v not in labels[m]:
                labels[m].append(v)
    if len(labels[0]) < 2:
        raise DatasetError(f"{source}: only one identity ({labels[0][0]!r}); a multilinear model "
                           "needs at least two")
    shape = tuple(len(l) for l in labels)
    first = None
    verts = None
    mask = np.zeros(shape, dtype=bool)
    total = len(index)
    for k, (vals, path) in enumerate(index.items()):
        if first is None:  # the first mesh gives the triangles and UVs of all
            mesh = read_mesh(path)
            v = mesh.vertices
            first = (path, mesh)
            verts = np.full(shape + v.shape, np.nan)
        else:
            v = _read_vertices(path)
        if len(v) != len(first[1].vertices):
            raise DatasetError(f"mesh {path} has {len(v)} vertices but {first[0]} has "
                               f"{len(first[1].vertices)}; all meshes must share one topology")
        idx = tuple(labels[m].index(vals[m]) for m in range(len(modes)))
        verts[idx] = v
        mask[idx] = True
        if progress is not None:
            progress(k + 1, total)
    if first is None or verts is None:
        raise DatasetError(f"{source}: no meshes")
    ref = first[1]
    if ref.faces.size == 0:
        raise MeshError(f"mesh {first[0]} has no triangles")
    ds_labels = tuple(tuple(l) for l in labels)
    missing = [tuple(ds_labels[m][i] for m, i in enumerate(ix)) for ix in zip(*np.nonzero(~mask))]
    if missing:
        log.warning("%s: %d of %d cells missing", source, len(missing), mask.size)
    prov = {"source": source, "modes": list(modes), "n_meshes": total,
            "missing": [list(c) for c in missing], "template_file": str(first[0])}
    return FaceDataset(verts, mask, tuple(modes), ds_labels, ref.faces, ref.uvs, None, None, prov)
