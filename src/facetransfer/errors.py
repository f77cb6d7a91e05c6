"""Project exceptions. All subclass :class:`ValueError` so callers can catch bad input uniformly.

The CLI turns any of these into one line on stderr and exit status 2.
"""


class FaceTransferError(ValueError):
    """Base class of every error facetransfer raises for bad input or bad data."""


class ShapeError(FaceTransferError):
    """An array has the wrong shape; the message names the shape found and the shape expected."""


class MeshError(FaceTransferError):
    """A mesh file is unreadable, empty, non-finite or has an unexpected topology."""


class RenderError(MeshError):
    """A mesh, camera or texture that cannot be rendered (:mod:`facetransfer.render`, whose
    public name it stays; here because :func:`facetransfer.geometry.check_mesh` raises it)."""


class DatasetError(FaceTransferError):
    """A manifest or data-set folder is inconsistent (duplicate or missing cells, mixed topology)."""


class ModelFileError(FaceTransferError):
    """A model file is truncated, altered, or written by a newer version."""


class AssetError(FaceTransferError):
    """An external asset is missing, cannot be downloaded, or fails its checksum."""


class VideoError(FaceTransferError):
    """A video is unreadable, empty, or has no face where one is needed."""


class TrackError(FaceTransferError):
    """Tracking could not proceed (bad initialisation, lost face, mismatched track file)."""


class OutputError(FaceTransferError):
    """An output cannot be written: bad path, exists without --overwrite, is also an input, or the
    write failed (no space left, read-only folder); the message names the output."""


class RewriteError(FaceTransferError):
    """Frames, tracks or a model that cannot be rendered back into footage."""


def interrupt_of(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or SIGTERM routed as one) behind ``exc``, or None.

    A signal whose handler raises while a numba-compiled function runs comes back as a
    ``SystemError`` ("returned a result with an exception set") caused by the interrupt:
    without this, an interrupt in the fit printed a traceback, exited 1 and lost the fit's
    progress."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__   # the kernel's SystemError is *caused* by it; one raised while
        # an interrupt was being handled (its context only) is a fault of its own
    return None


class plain_interrupts:
    """Context manager: an interrupt wrapped in a ``SystemError`` (:func:`interrupt_of`)
    raised as the interrupt itself, so that whatever keeps progress on Ctrl-C keeps it."""

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if kind is not None and issubclass(kind, SystemError):
            stop = interrupt_of(exc)
            if stop is not None:
                raise stop from None
        return False
