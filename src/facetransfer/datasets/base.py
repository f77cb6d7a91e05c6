"""The Cartesian product of corresponded meshes (§4.1, Fig. 3) as one array with a mask."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import DatasetError


@dataclass(frozen=True)
class FaceDataset:
    """Meshes in one topology arranged by attribute (identity, expression[, viseme], ...).

    Attributes
    ----------
    vertices : (d_1, ..., d_K, n_vertices, 3) float64
        Cell ``(i_1, ..., i_K)`` holds the mesh of identity ``i_1`` with attribute values
        ``i_2 ... i_K``; missing cells are NaN.
    mask : (d_1, ..., d_K) bool
        True where the mesh is present.
    mode_names : tuple of str
        Attribute mode names, e.g. ``("identity", "expression", "viseme")``; the first is the
        identity mode by convention.
    labels : tuple of tuple of str
        Label of every index of every mode (e.g. identity ids, expression names).
    faces : (n_faces, 3) int64
        Triangles shared by all meshes.
    uvs : (n_vertices, 2) float64 or None
    landmarks : (68,) int64 or None
        iBUG-68 landmark vertex indices into ``vertices`` (0-based, iBUG order).
    vertex_subset : (n_vertices,) int64 or None
        Indices of these vertices in the source template (e.g. ICT-FaceKit full mesh).
    provenance : dict
        Recipe, seed, source files and versions: everything needed to rebuild it.
    """

    vertices: np.ndarray
    mask: np.ndarray
    mode_names: tuple[str, ...]
    labels: tuple[tuple[str, ...], ...]
    faces: np.ndarray
    uvs: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    vertex_subset: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        K = len(self.mode_names)
        shape = self.vertices.shape
        if self.vertices.ndim != K + 2 or shape[-1] != 3:
            raise DatasetError(f"vertices must be (d_1..d_{K}, n_vertices, 3), got {shape}")
        if self.mask.shape != shape[:K]:
            raise DatasetError(f"mask shape {self.mask.shape} does not match cells {shape[:K]}")
        if len(self.labels) != K or any(len(l) != d for l, d in zip(self.labels, shape[:K])):
            raise DatasetError(f"labels {[len(l) for l in self.labels]} do not match cells {shape[:K]}")

    @property
    def shape(self) -> tuple[int, ...]:
        """Cells per attribute mode, ``(d_1, ..., d_K)``."""
        return tuple(self.mask.shape)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[-2])

    def missing_cells(self) -> list[tuple[str, ...]]:
        """Labels of every missing cell, e.g. ``[("id03", "smile"), ...]``."""
        return [tuple(self.labels[k][i] for k, i in enumerate(idx))
                for idx in zip(*np.nonzero(~self.mask))]

    def data_tensor(self) -> np.ndarray:
        """The data tensor of Fig. 3, vertex mode first: ``(3 n_vertices, d_1, ..., d_K)``.

        Coordinates are vertex-major (x0, y0, z0, x1, ...). Missing cells are NaN.
        """
        K = len(self.mode_names)
        v = self.vertices.reshape(self.shape + (-1,))
        return np.moveaxis(v, K, 0)

    def with_vertices(self, vertices: np.ndarray, mask: np.ndarray | None = None,
                      **provenance) -> "FaceDataset":
        """A copy with new vertices (same shape), e.g. after imputation."""
        prov = dict(self.provenance)
        prov.update(provenance)
        return FaceDataset(vertices, self.mask if mask is None else mask, self.mode_names,
                           self.labels, self.faces, self.uvs, self.landmarks, self.vertex_subset,
                           prov)
