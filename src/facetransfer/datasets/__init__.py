"""Face data sets (§4.1): Cartesian products of corresponded meshes as :class:`FaceDataset`."""

from .base import FaceDataset

__all__ = ["FaceDataset"]
