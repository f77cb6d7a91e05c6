"""Face tracking in monocular video (Vlasic et al. 2005, §5.1 tracking, §5.2 initialisation).

Two trackers write the same :class:`Track` (:mod:`.result`, its file):

* the capture tracker, the default of every command (:mod:`.capture`): Face Landmarker's
  points detected through the whole clip (:mod:`.detect`, :mod:`.video_detect` on two
  processes, :mod:`.face_crop` for small faces, :mod:`.shots` for an edited clip's cuts), the
  identity fitted over frames spread through it, then every frame's pose and ARKit
  activations fitted to the points and the flow (:mod:`.capture_points`, :mod:`.fit2d`,
  :mod:`.gaze`, :mod:`.scores`; one frame's fit :mod:`.capture_frame`, the lips' contact
  :mod:`.lip_contact`, MediaPipe's points on the model's surface :mod:`.dense`, the frames the
  detector may skip :mod:`.skip_rule`, Face Landmarker's results as arrays :mod:`.mp_result`);
  its progress kept (:mod:`.detect_checkpoint`, :mod:`.fit_checkpoint`);
* the paper's KLT tracker (``--tracker klt``; ``flow`` in ``transfer``, ``puppet`` and
  ``demo``): :mod:`.camera` (weak-perspective pose, Eq. (7)), :mod:`.klt` (symmetric KLT
  terms, Eq. (6)), :mod:`.solver` (Eq. (8), (9)), :mod:`.pair` (one frame pair, Eq.
  (6)-(9)), :mod:`.init` (§5.2), :mod:`.tracker` (initialisation, snap and passes),
  :mod:`.options` (its options), :mod:`.checkpoint`.

Around them: :mod:`.obtain` (a track for a video: a file given, the cache, or tracked; in a
forked process beside another), :mod:`.cache` (the track cache), :mod:`.presets` and
:mod:`.settings` (the commands' tracker options), :mod:`.landmarks` (MediaPipe-478 to iBUG-68;
:mod:`.calibration`, that correspondence calibrated against points of known truth),
:mod:`.aspect` (the frames as the tracker sees them), :mod:`.project` (a track's landmarks
and frames), :mod:`.smooth`, :mod:`.overlay` (drawing the fit on frames), :mod:`.occlusion`
(a hand, a microphone or glasses over the mouth or the eyes: ``track --occluders``).

Typical use::

    from facetransfer.default_model import load_default_model
    from facetransfer.track.capture import capture_video

    track = capture_video("clip.mp4", load_default_model())   # as `facetransfer track`
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
