"""The house's numba decorator (:func:`_maybe_njit`), in the base layer so that every layer's
kernels share it: the mesh's vertex normals (:mod:`facetransfer.geometry`, which the scans'
template fitting uses below the renderer), the camera (:mod:`facetransfer.render.cameras`), the
rasteriser and the rewrite's kernels."""

from __future__ import annotations

try:  # numba is a hard dependency; the fallback keeps the module importable without it
    import numba

    _HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    _HAVE_NUMBA = False


def _maybe_njit(fn, *, inline: bool = False):
    """``fn`` compiled by numba (cached, no GIL, numpy's error model). ``inline``: inlined
    into the kernels that call it, at numba's IR level (a cached kernel is its own LLVM
    module, so LLVM does not inline across kernels: a small helper called per pixel would
    otherwise cost a call with every array argument spilled to the stack)."""
    if not _HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy",
                      inline="always" if inline else "never")(fn)
