"""The keys of a ``synth-video`` performance spec
(:func:`facetransfer.synth.performance_from_spec`), apart from :mod:`facetransfer.synth` so that
the command line names them in its help without importing the renderer at start-up
(:data:`facetransfer.synth.SPEC_KEYS` is this one)."""

from __future__ import annotations

__all__ = ["SPEC_KEYS", "MAX_FRAMES"]

#: The keys of a performance spec: its own, an oscillating pose's and a pose keyframe's.
SPEC_KEYS = {"spec": ("n_frames", "fps", "size", "identity", "tracks", "pose"),
             "pose": ("yaw_deg", "pitch_deg", "roll_deg", "translate_px", "scale", "period_s",
                      "fill", "keys"),
             "pose.keys": ("yaw_deg", "pitch_deg", "roll_deg", "tx", "ty", "scale")}

#: The most frames a synthetic clip has, from ``--frames`` or the spec's ``n_frames`` alike (11
#: hours at 25 fps; 10**30 was numpy's OverflowError traceback).
MAX_FRAMES = 1_000_000
