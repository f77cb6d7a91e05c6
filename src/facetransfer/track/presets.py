"""Tracking presets of a transfer: the optical-flow tracker's settings (§5.1) for a speed."""

from __future__ import annotations

from ..errors import RewriteError

__all__ = ["SPEED_PRESETS", "DEFAULT_SPEED", "TRACK_METHODS", "DETECT_EVERY",
           "track_options", "check_track_method"]

#: Tracking presets of a transfer (:func:`track_options`), fastest first.
SPEED_PRESETS = ("fast", "balanced", "quality")
#: The preset of the transfer and the CLI: as accurate as "balanced" on the synthetic footage
#: and the real clips measured (see :func:`track_options`), a third of its time.
DEFAULT_SPEED = "fast"
#: Per preset, the transfer's clips (its target and its sources) are shown to the capture
#: tracker's detector one frame of this many (:func:`facetransfer.track.detect.detect_clip`'s
#: ``every``; the frames between interpolated), a source's also every frame where the eyes
#: move (its ``eyes``, :mod:`facetransfer.track.skip_rule`: its blinks are the performance's).
#: With ``"fast"``, on issue 13's pair the target's detection takes 2.0 instead of 3.3 CPU-s,
#: its activations correlate 0.98-1.00 with those of a detection of every frame (BENCHMARKS.md,
#: "Thirty-ninth session"); the source's blinks keep their peaks (r 0.96-1.00 against every
#: frame's, "Forty-sixth session").
DETECT_EVERY = {"fast": 2, "balanced": 1, "quality": 1}
#: Trackers of :func:`facetransfer.track.obtain.obtain_track`.
TRACK_METHODS = ("auto", "capture", "flow", "landmarks")


def check_track_method(method) -> None:
    """Raise :class:`RewriteError` unless ``method`` is one of :data:`TRACK_METHODS`."""
    if method not in TRACK_METHODS:
        hint = " (the optical-flow tracker that `facetransfer track --tracker` calls klt is " \
            "'flow' here)" if method == "klt" else ""
        raise RewriteError(f"tracking method must be auto, capture, flow or landmarks, got "
                           f"{method!r}{hint}")


def track_options(speed: str = DEFAULT_SPEED):
    """Settings of the optical-flow tracker (§5.1) for a speed preset.

    ``"fast"`` (the default of the transfer,
    :data:`facetransfer.rewrite_options.DEFAULT_SPEED`) makes a single pass (the identity
    comes from the snap of §5.2) on two pyramid levels with 500 tracked vertices, 7x7
    KLT windows, a shorter snap, and chooses the tracked vertices anew every 8 frame pairs
    (``TrackOptions.reselect``). ``"balanced"`` is the tracker's own default
    (:class:`facetransfer.track.TrackOptions`: two passes, three pyramid levels, a thousand
    vertices, the initial snap and the key-frame term) with a new choice of vertices every 4
    pairs; ``"quality"`` makes three passes and two snap rounds.

    Measured (``benchmarks/bench_transfer.py``, BENCHMARKS.md): ``"fast"`` tracks about four
    times faster than ``"balanced"`` with the same accuracy on the synthetic footage
    (landmark error 1.4 vs 1.5 px, face PSNR within 0.2 dB) and on four real clips (200
    frames each, landmark error against MediaPipe's 0.065 vs 0.066 of the eye distance).
    ``"balanced"`` and ``"quality"`` remain for harder footage (fast motion, where the third
    pyramid level helps; occlusions, where more points do).

    Parameters
    ----------
    speed : {"fast", "balanced", "quality"}

    Returns
    -------
    TrackOptions

    Raises
    ------
    RewriteError
        An unknown preset.
    """
    from .options import TrackOptions

    if speed not in SPEED_PRESETS:
        raise RewriteError(f"speed must be one of {', '.join(SPEED_PRESETS)}, got {speed!r}")
    if speed == "balanced":
        return TrackOptions(reselect=4)
    if speed == "fast":
        return TrackOptions(passes=1, levels=2, n_points=500, snap_frames=4, reselect=8,
                            half_window=3)
    return TrackOptions(passes=3, snap_rounds=2)
