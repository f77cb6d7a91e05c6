"""Face tracking in monocular video (Vlasic et al. 2005, §5.1 tracking, §5.2 initialisation).

Modules: :mod:`.result` (the :class:`Track` result and its file), :mod:`.camera` (weak-perspective
pose, Eq. (7)), :mod:`.klt` (symmetric KLT terms, Eq. (6)), :mod:`.solver` (Eq. (8), (9)),
:mod:`.landmarks` (MediaPipe-478 to iBUG-68), :mod:`.init` (§5.2), :mod:`.pair` (one frame pair,
Eq. (6)-(9)), :mod:`.tracker` (initialisation, snap and passes), :mod:`.options` (its options),
:mod:`.frames` (video frames), :mod:`.smooth` (temporal smoothing), :mod:`.overlay` (drawing the
fit on frames).

Typical use::

    from facetransfer.model import load_model
    from facetransfer.track import TrackOptions, track_video

    track = track_video("clip.mp4", load_model("bilinear.npz"), init="auto",
                        options=TrackOptions(passes=2, anchor=True))
    track.save("clip.track.npz")
"""

from .result import Track

__all__ = ["Track", "TrackOptions", "FaceTracker", "track_video"]

#: names imported on first use: the KLT tracker brings numba and scipy, which a command that
#: only needs a track file or the presets (``facetransfer --help``, the CLI's parser) skips
_LAZY = {"TrackOptions": "tracker", "FaceTracker": "tracker", "track_video": "tracker"}


def __getattr__(name: str):
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
