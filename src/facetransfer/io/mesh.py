"""Mesh input and output.

Conventions: vertices ``(n_vertices, 3) float64``, triangles ``(n_faces, 3) int64``, UVs
``(n_vertices, 2) float64`` with v pointing up (OBJ convention). Quads are split into two triangles.
Vertex order is always kept exactly as in the file (``trimesh`` is called with ``process=False``),
because correspondence across a data set is by vertex index.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MeshError
from .atomic import atomic_path


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : (n_vertices, 3) float64
    faces : (n_faces, 3) int64
    uvs : (n_vertices, 2) float64 or None
        Per-vertex texture coordinates, when the file has them and they are per-vertex
        (for OBJ files with separate UV indices, the UV of each vertex's first use).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None


def _check_vertices(v: np.ndarray, path: str | os.PathLike) -> np.ndarray:
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must be (n, 3), got {v.shape} in {path}")
    if v.shape[0] == 0:
        raise MeshError(f"mesh {path} has no vertices")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
        raise MeshError(f"mesh {path} has {bad} vertices with NaN or infinite coordinates")
    return v


def read_obj_vertices(path: str | os.PathLike) -> np.ndarray:
    """Read only the ``v`` lines of an OBJ file, fast (no faces, no processing).

    Parameters
    ----------
    path : path-like
        Wavefront OBJ file.

    Returns
    -------
    vertices : (n_vertices, 3) float64
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise MeshError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    # a byte-order mark hid the first vertex; lines of two numbers were read three at a time
    lines = [ln[2:].decode("utf-8", "replace") for ln in data.removeprefix(BOM).split(b"\n")
             if ln.startswith(b"v ")]
    if not lines:
        raise MeshError(f"mesh {path} has no vertices")
    return _check_vertices(_floats(lines, 3, path, "vertex"), path)


def _floats(rows: list[str], k: int, path, what: str) -> np.ndarray:
    """``k`` numbers from each of ``rows`` (extra columns ignored), as an (n, k) float64 array."""
    try:
        cols = [s.split()[:k] for s in rows]
        if any(len(c) < k for c in cols):
            raise ValueError
        return np.array(cols, dtype=np.float64).reshape(-1, k)
    except ValueError:
        bad = next((n for n, s in enumerate(rows) if len(s.split()) < k), None)
        raise MeshError(f"mesh {path} has malformed {what} lines (each needs {k} numbers"
                        + (f"; {what} {bad + 1} has {len(rows[bad].split())}" if bad is not None
                           else "") + ")") from None


#: A UTF-8 byte-order mark, which some editors put before an OBJ's first line.
BOM = b"\xef\xbb\xbf"

#: Face indices beyond this are out of every mesh's range (and of int64's: OverflowError).
_INDEX_LIMIT = 1 << 40


def _face_index(token: str, path) -> int:
    try:
        i = int(token)
    except ValueError:
        raise MeshError(f"mesh {path} has a malformed face index {token!r} (expected an "
                        "integer)") from None
    if abs(i) > _INDEX_LIMIT:
        raise MeshError(f"mesh {path} has a face index {token} outside every mesh's range")
    return i


def _obj_index(f: np.ndarray, n: int) -> np.ndarray:
    """OBJ indices (1-based; negative counts from the end) -> 0-based; -1 where out of range."""
    g = np.where(f < 0, f + n, f - 1)
    return np.where((f == 0) | (g < 0) | (g >= n), -1, g)


def read_obj(path: str | os.PathLike) -> Mesh:
    """Read an OBJ file keeping vertex order; polygons are fanned into triangles, UVs taken per
    vertex.

    Returns
    -------
    Mesh

    Raises
    ------
    MeshError
        Unreadable file, malformed ``v`` / ``vt`` / ``f`` lines, face or texture indices out of
        range, non-finite coordinates (the message names the file).
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read().removeprefix(BOM).decode("utf-8", errors="replace")
    except OSError as exc:
        raise MeshError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    verts: list[str] = []
    uvs: list[str] = []
    tris: list[tuple[int, int, int]] = []
    tri_uv: list[tuple[int, int, int]] = []
    for line in data.splitlines():
        if line.startswith("v "):
            verts.append(line[2:])
        elif line.startswith("vt "):
            uvs.append(line[3:])
        elif line.startswith("f "):
            parts = [q.split("/") for q in line[2:].split()]
            if len(parts) < 3:
                raise MeshError(f"mesh {path} has a face with {len(parts)} vertices (at least 3)")
            vi = [_face_index(q[0], path) for q in parts]
            ti = [_face_index(q[1], path) if len(q) > 1 and q[1] else 0 for q in parts]
            for k in range(1, len(parts) - 1):
                tris.append((vi[0], vi[k], vi[k + 1]))
                tri_uv.append((ti[0], ti[k], ti[k + 1]))
    if not verts:
        raise MeshError(f"mesh {path} has no vertices")
    v = _floats(verts, 3, path, "vertex")
    _check_vertices(v, path)
    n = len(v)
    f = _obj_index(np.array(tris, dtype=np.int64).reshape(-1, 3), n)
    if f.size and f.min() < 0:
        raise MeshError(f"mesh {path} has face indices outside 1..{n}")
    uv = None
    if uvs:
        t = _floats(uvs, 2, path, "texture coordinate")
        if not np.all(np.isfinite(t)):
            raise MeshError(f"mesh {path} has NaN or infinite texture coordinates")
        raw = np.array(tri_uv, dtype=np.int64).reshape(-1, 3)
        if raw.size and (raw != 0).all():
            ti = _obj_index(raw, len(t))
            if ti.min() < 0:
                raise MeshError(f"mesh {path} has texture (vt) indices outside 1..{len(t)}")
            uv = np.zeros((n, 2))
            fv, tv = f.ravel(), ti.ravel()
            first = np.unique(fv, return_index=True)
            uv[first[0]] = t[tv[first[1]]]
    return Mesh(v, f, uv)


def _unread_mesh(p: Path, exc: Exception) -> str:
    """Why the file ``p`` trimesh could not read is no mesh: a track, model or truth archive, a
    video, a Live Link Face take, an image ... named as such, or a file of a type trimesh reads
    no mesh from said with the mesh formats (it said trimesh's "file_type 'csv' not
    supported"); else trimesh's first line."""
    import trimesh

    from .npz import NOT_NPZ, content_kind

    kind = content_kind(p)
    what = "an .npz archive (a track, a model, a ground truth)" if p.suffix.lower() == ".npz" \
        else kind if kind not in (None, NOT_NPZ) and "glTF" not in kind else None
    if what is None and p.suffix.lower().lstrip(".") not in trimesh.available_formats():
        what = f"a file of type {p.suffix or '(no extension)'}"
    if what is not None:
        return f"mesh file {p} is {what}, not a mesh: give one of {', '.join(MESH_SUFFIXES)}"
    msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
    return f"cannot read mesh {p}: {msg}"


def read_mesh(path: str | os.PathLike) -> Mesh:
    """Read any mesh trimesh can read (OBJ, PLY, STL, OFF, GLB …) without reordering vertices.

    Raises
    ------
    MeshError
        Unreadable, empty, non-finite, or not a mesh.
    """
    from .npz import check_input_file

    p = check_input_file(path, "mesh file", MeshError)
    if p.suffix.lower() == ".obj":
        return read_obj(p)
    import trimesh

    try:
        loaded = trimesh.load(p, process=False)
        if isinstance(loaded, trimesh.PointCloud):
            v = np.asarray(loaded.vertices, dtype=np.float64)
            f = np.zeros((0, 3), np.int64)
        else:
            if isinstance(loaded, trimesh.Scene):
                loaded = trimesh.load(p, process=False, force="mesh")
            v = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
            f = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    except Exception as exc:  # trimesh raises many kinds
        raise MeshError(_unread_mesh(p, exc)) from None
    _check_vertices(v, p)
    f = f.reshape(-1, 3) if f.size else np.zeros((0, 3), np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise MeshError(f"mesh {p} has face indices outside 0..{len(v) - 1}")
    if p.suffix.lower() == ".ply":
        _check_ply_counts(p, len(v), len(f))
    uv = None
    visual = getattr(loaded, "visual", None)
    if visual is not None and getattr(visual, "uv", None) is not None and len(visual.uv) == len(v):
        uv = np.asarray(visual.uv, dtype=np.float64)
    return Mesh(v, f, uv)


def _ply_counts(path: Path) -> dict[str, int]:
    """The element counts a PLY file's header declares (``{"vertex": n, "face": m}``); empty
    where the header cannot be read."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return {}
    end = head.find(b"end_header")
    counts = {}
    for line in head[:end if end >= 0 else 0].decode("latin-1").splitlines():
        words = line.split()
        if len(words) == 3 and words[0] == "element" and words[1].isidentifier() and \
                words[2].isdigit():
            counts[words[1]] = int(words[2])
    return counts


def _check_ply_counts(path: Path, n_vertices: int, n_triangles: int) -> None:
    """MeshError where a PLY file holds fewer vertices or faces than its header declares: an
    ASCII file cut short was read as the vertices before the cut and no faces, said nowhere
    (each face is one triangle or more)."""
    counts = _ply_counts(path)
    if counts.get("vertex", n_vertices) != n_vertices or \
            counts.get("face", 0) > n_triangles:
        raise MeshError(f"mesh {path} is truncated: its header declares "
                        f"{counts.get('vertex', 0)} vertices and {counts.get('face', 0)} faces, "
                        f"it holds {n_vertices} and {n_triangles} triangles")


#: The mesh files :func:`write_mesh` writes (OBJ itself, the others through trimesh's
#: exporters), the first the one suggested for a misnamed output.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb")


def check_mesh_output(path: str | os.PathLike, *, flag: str = "--out") -> Path:
    """Refuse, before any work, a mesh output whose extension is not one of
    :data:`MESH_SUFFIXES` (:func:`facetransfer.io.output_names.check_output_suffix`)."""
    from .output_names import check_output_suffix

    return check_output_suffix(path, MESH_SUFFIXES, "a mesh", flag=flag)


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, *,
               uvs: np.ndarray | None = None, colors: np.ndarray | None = None,
               overwrite: bool = True) -> Path:
    """Write a mesh atomically; format by extension (``.obj`` written directly, others via trimesh).

    Parameters
    ----------
    vertices : (n_vertices, 3) float
    faces : (n_faces, 3) int
    uvs : (n_vertices, 2) float, optional (OBJ only)
    colors : (n_vertices, 3) uint8, optional (PLY via trimesh)
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _check_vertices(v, path)
    p = check_mesh_output(path, flag="mesh")
    with atomic_path(p, overwrite=overwrite) as tmp:
        if p.suffix.lower() == ".obj":
            with open(tmp, "w") as fh:
                fh.write("# written by facetransfer\n")
                np.savetxt(fh, v, fmt="v %.6f %.6f %.6f")
                if uvs is not None:
                    np.savetxt(fh, np.asarray(uvs, dtype=np.float64), fmt="vt %.6f %.6f")
                    np.savetxt(fh, np.repeat(f + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
                else:
                    np.savetxt(fh, f + 1, fmt="f %d %d %d")
        else:
            import trimesh

            m = trimesh.Trimesh(v, f, process=False, vertex_colors=colors)
            m.export(tmp, file_type=p.suffix.lower().lstrip("."))
    return p
