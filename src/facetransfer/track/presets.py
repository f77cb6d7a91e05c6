"""Tracking presets of a transfer: the optical-flow tracker's settings (§5.1) for a speed."""

from __future__ import annotations

from ..rewrite_options import DEFAULT_SPEED, SPEED_PRESETS, check_mode

__all__ = ["SPEED_PRESETS", "DEFAULT_SPEED", "track_options"]


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
    from .tracker import TrackOptions

    check_mode("speed", speed, SPEED_PRESETS)
    if speed == "balanced":
        return TrackOptions(reselect=4)
    if speed == "fast":
        return TrackOptions(passes=1, levels=2, n_points=500, snap_frames=4, reselect=8,
                            half_window=3)
    return TrackOptions(passes=3, snap_rounds=2)
