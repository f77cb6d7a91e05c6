"""The house's numba decorator (:func:`maybe_njit`), in the base layer so that every layer's
kernels share it: the mesh's vertex normals (:mod:`facetransfer.geometry`, which the scans'
template fitting uses below the renderer), the camera (:mod:`facetransfer.render.cameras`), the
rasteriser and the rewrite's kernels. Each of them imports it from here, most as
``from .jit import maybe_njit as _maybe_njit`` (a name of the module's own, not re-exported).

The tracker's two kernel modules (:mod:`facetransfer.track.fit2d`, :mod:`facetransfer.track.gaze`)
keep numba's ``njit(cache=True)``: Python's error model, where a division by zero raises
(``ZeroDivisionError``) instead of giving ``inf`` or ``nan`` as here.
"""

from __future__ import annotations

__all__ = ["HAVE_NUMBA", "maybe_njit", "read_only"]

try:  # numba is a hard dependency; the fallback keeps the module importable without it
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    HAVE_NUMBA = False


def maybe_njit(fn, *, inline: bool = False):
    """``fn`` compiled by numba (cached, no GIL, numpy's error model). ``inline``: inlined
    into the kernels that call it, at numba's IR level (a cached kernel is its own LLVM
    module, so LLVM does not inline across kernels: a small helper called per pixel would
    otherwise cost a call with every array argument spilled to the stack)."""
    if not HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy",
                      inline="always" if inline else "never")(fn)


def read_only(a):
    """A read-only view of the array ``a`` (no copy), for a kernel argument it only reads.

    numba compiles one signature per argument type, and a read-only array is another type: a
    photo target's frames are one shared read-only view, so a kernel given them compiled (and
    cached) a second version mid-run. Passing the view always keeps one compiled signature
    whatever the caller's array."""
    view = a.view()
    view.flags.writeable = False
    return view
