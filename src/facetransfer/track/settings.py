"""Which tracker runs, and with what options: one rule for ``track``, ``batch`` and the library.

The capture tracker (:mod:`facetransfer.track.capture`) is the default; the paper's KLT tracker
(:mod:`facetransfer.track.tracker`) runs when asked for, or when first-frame feature points are
given (only it starts from them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import TrackError
from .capture import CaptureOptions
from .options import TrackOptions

__all__ = ["TRACKERS", "TrackerSettings"]

#: Names of the trackers.
TRACKERS = ("capture", "klt")


@dataclass(frozen=True)
class TrackerSettings:
    """The tracker and the options of each.

    Attributes
    ----------
    tracker : {"capture", "klt"} or None
        None: capture, unless first-frame points are given (then klt).
    klt : TrackOptions
    capture : CaptureOptions
    """

    tracker: str | None = None
    klt: TrackOptions = field(default_factory=TrackOptions)
    capture: CaptureOptions = field(default_factory=CaptureOptions)

    def __post_init__(self) -> None:
        if self.tracker is not None and self.tracker not in TRACKERS:
            raise TrackError(f"tracker must be one of {', '.join(TRACKERS)}, got {self.tracker!r}")

    def choose(self, init) -> str:
        """The tracker for a clip whose first-frame points are ``init`` (``"auto"``: none given).

        Raises
        ------
        TrackError
            Points given to the capture tracker (it detects the face on every frame).
        """
        auto = isinstance(init, str) and init == "auto"
        if self.tracker is None:
            return "capture" if auto else "klt"
        if self.tracker == "capture" and not auto:
            raise TrackError("first-frame points (--init) are for the klt tracker; the capture "
                             "tracker detects the face on every frame")
        return self.tracker
