"""The frames as the tracker sees them: at their shown shape, and of interlaced video one
field's instant (:class:`View`).

Some videos store pixels that are shown wider or narrower than tall (a sample aspect ratio,
:attr:`facetransfer.io.video.VideoInfo.sar`): HDV's 1440x1080 is shown 1920x1080 (4:3), DV's
720x480 at 10:11 or 40:33, and ``driving_d9`` of the data folder, 512x480, at 15:16. In the
stored pixels the face is squeezed or stretched across; the model's weak-perspective camera
(Eq. (7), one scale for both axes) would fit that stretch with a wider or narrower person and
other expressions (an HDV-style copy of ``driving_d6``: jawOpen's mean 0.53 against 0.37 in
square pixels, mouthPucker's 0.47 against 0.25), and Face Landmarker would see the squeezed face
too.

So the capture tracker sees the frames resampled to square pixels (their height kept, their
width ``round(W sar)``: :func:`display_frames`), fits there with the paper's camera, and its
track is then expressed in the stored pixels (:func:`stored_pixels`): the camera keeps its
scale and rotation and gains the pixel aspect ``a = W_shown / W`` (``x = s (R X)_x / a + t_x``,
:class:`facetransfer.render.WeakPerspective`), so the rewrite, the overlay and the texture see
the stored frames as they are, while the identity, the expression and the head pose exported
are the face's own.

Coordinates map between the two by the resampling's pixel centres (OpenCV's
``cv2.resize``): ``x_stored = (x_shown + 0.5) / a - 0.5``, ``y`` unchanged.

An interlaced video (DV, HDV, AVCHD, broadcast) stores in each frame two fields, its even and
its odd rows, filmed half a frame apart: where the face moves, its rows alternate between two
instants (a blink half done, the jaw at two openings). The tracker sees the field shown first
alone (:func:`field_frame`: its rows kept, the other field's interpolated between them, so no
row moves), and the track is that field's instant. On an interlaced copy of ``driving_d6``
(30 fps woven into 15 fps fields) against the progressive frames of its first fields: jawOpen r
0.978 woven, 0.995 one field; eyeBlinkRight 0.953 and 0.994, its largest error 0.67 and 0.17.

:func:`~facetransfer.io.video_display.shown_width` is :mod:`facetransfer.io.video_display`'s,
importable from here too.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from ..io.video_display import first_field, shown_width
from ..io.video_read import video_info

log = logging.getLogger(__name__)

__all__ = ["SQUARE", "View", "shown_width", "video_aspect", "aspect_of", "display_frames",
           "field_frame", "to_stored_x", "to_shown_x", "stored_pixels", "warn_stored_fit"]

#: The pixel aspect of square pixels.
SQUARE = 1.0


def aspect_of(width: int, sar: tuple[int, int]) -> float:
    """The pixel aspect the frames are resampled by: ``shown_width / width`` (exactly what
    :func:`display_frames` does, which differs from ``sar`` by the rounding to whole pixels);
    :data:`SQUARE` where the rounding leaves the width as it is."""
    w = int(width)
    return shown_width(w, sar) / w if w > 0 else SQUARE


def video_aspect(video) -> float:
    """The pixel aspect of a video file (:func:`aspect_of` its width and sample aspect
    ratio); :data:`SQUARE` for an array of frames, which carries none."""
    if not isinstance(video, (str, os.PathLike)):
        return SQUARE
    info = video_info(video)
    return aspect_of(info.size[0], info.sar)


@dataclass(frozen=True)
class View:
    """How the tracker is shown a video's frames (module notes).

    Attributes
    ----------
    aspect : float
        The pixels' aspect: frames resampled by it to square pixels (:func:`display_frames`).
    field : {"top", "bottom"} or None
        Interlaced video: the field shown first, alone (:func:`field_frame`); None:
        progressive.
    """

    aspect: float = SQUARE
    field: str | None = None

    def __post_init__(self) -> None:
        a = float(self.aspect)
        if not np.isfinite(a) or a <= 0:
            raise ValueError(f"pixel aspect must be > 0, got {self.aspect}")
        if self.field not in (None, "top", "bottom"):
            raise ValueError(f"field must be 'top', 'bottom' or None, got {self.field!r}")
        object.__setattr__(self, "aspect", a)

    @classmethod
    def of(cls, video) -> "View":
        """The view of a video file (its pixel aspect, :func:`video_aspect`, and the field it
        shows first, :func:`facetransfer.io.video_display.first_field`); an array of frames
        carries neither."""
        if not isinstance(video, (str, os.PathLike)):
            return cls()
        return cls(video_aspect(video), first_field(video))

    def frames(self, frames: Iterable) -> Iterator:
        """``frames`` as the tracker sees them (None placeholders pass)."""
        if self.field is not None:
            frames = (None if f is None else field_frame(f, self.field) for f in frames)
        return display_frames(frames, self.aspect)


def field_frame(frame: np.ndarray, field: str) -> np.ndarray:
    """One field of an interlaced frame ``(H, W, ...)`` at full height: its rows (``"top"``:
    0, 2, 4, ...; ``"bottom"``: 1, 3, ...) kept in place, each row of the other field the mean
    of the field's rows beside it (rounded; the field's own row at the frame's edge)."""
    f = np.asarray(frame)
    k = 0 if field == "top" else 1
    own = f[k::2].astype(np.uint16)
    out = f.copy()
    # the other field's rows: 1 - k, 3 - k, ...; row r lies between own rows (r - k - 1) / 2
    # and (r - k + 1) / 2 where both exist
    other = np.arange(1 - k, f.shape[0], 2)
    lo = np.clip((other - k - 1) // 2, 0, len(own) - 1)
    hi = np.clip((other - k + 1) // 2, 0, len(own) - 1)
    out[other] = ((own[lo] + own[hi] + 1) >> 1).astype(f.dtype)
    return out


def warn_stored_fit(video, tracker: str) -> None:
    """Warn that ``tracker`` (the paper's optical-flow tracker, or a fit to a landmark file)
    fits a video as stored: of non-square pixels, its identity and head pose carry the
    stretch; interlaced, its frames hold two instants. The default capture tracker sees
    neither (:class:`View`). Silent for square, progressive pixels and arrays."""
    view = View.of(video)
    if view.aspect != SQUARE:
        log.warning("%s: its pixels are %.3g times as wide as tall; the %s fits them as "
                    "stored, so the identity and head pose carry that stretch (the default "
                    "capture tracker fits the face at its shown shape)", video, view.aspect,
                    tracker)
    if view.field is not None:
        log.warning("%s is interlaced; the %s sees its frames woven, two instants in each "
                    "(the default capture tracker sees one field)", video, tracker)


#: Narrowed to at least this share of the stored width, frames are resampled bilinearly: a
#: shrink this mild leaves little to alias, and OpenCV's area average takes a slow general
#: path for fractional ratios (512 -> 480 columns: 1.57 against 0.53 ms a frame, 0.3 s of a
#: 10-second clip's capture). Narrower ones are area-averaged.
LINEAR_SHRINK = 0.75


def display_frames(frames: Iterable, aspect: float) -> Iterator:
    """``frames`` (H, W, 3) resampled to ``round(W aspect)`` columns (``cv2.INTER_LINEAR``
    when wider or narrowed to no less than :data:`LINEAR_SHRINK` of the width,
    ``cv2.INTER_AREA`` when narrower still), rows as they are; items that are None (a
    skipped frame's placeholder) pass as they are. With :data:`SQUARE`, ``frames`` itself."""
    if aspect == SQUARE:
        yield from frames
        return
    import cv2

    for fr in frames:
        if fr is None:
            yield None
            continue
        H, W = fr.shape[:2]
        w = max(1, int(round(W * aspect)))
        mode = cv2.INTER_AREA if w < LINEAR_SHRINK * W else cv2.INTER_LINEAR
        yield cv2.resize(np.ascontiguousarray(fr), (w, H), interpolation=mode)


def to_stored_x(x: np.ndarray, aspect: float) -> np.ndarray:
    """Shown-pixel columns ``x`` as stored-pixel columns: ``(x + 0.5) / aspect - 0.5``."""
    return (np.asarray(x, np.float64) + 0.5) / aspect - 0.5


def to_shown_x(x: np.ndarray, aspect: float) -> np.ndarray:
    """Stored-pixel columns ``x`` as shown-pixel columns (the inverse of
    :func:`to_stored_x`)."""
    return (np.asarray(x, np.float64) + 0.5) * aspect - 0.5


def _stored_points(P: np.ndarray | None, aspect: float) -> np.ndarray | None:
    if P is None:
        return None
    out = np.array(P, np.float64, copy=True)
    out[..., 0] = to_stored_x(out[..., 0], aspect)
    return out


def stored_pixels(track, aspect: float):
    """A track fitted in shown (square) pixels expressed in the stored pixels of a video of
    pixel aspect ``aspect`` (module notes): translations, tracked and detected points mapped
    by :func:`to_stored_x`, the camera given the pixel aspect. ``track`` itself for
    :data:`SQUARE`.

    Parameters
    ----------
    track : Track
        With :attr:`~facetransfer.track.result.Track.pixel_aspect` 1 and ``frame_size`` the
        stored frames'.
    aspect : float
        ``W_shown / W`` (:func:`aspect_of`).
    """
    if aspect == SQUARE:
        return track
    t = np.array(track.translation, np.float64, copy=True)
    t[:, 0] = to_stored_x(t[:, 0], aspect)
    return dataclasses.replace(track, translation=t, pixel_aspect=float(aspect),
                               landmarks2d=_stored_points(track.landmarks2d, aspect),
                               detections2d=_stored_points(track.detections2d, aspect))
