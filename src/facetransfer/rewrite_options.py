"""The options of a video rewrite (Vlasic et al. 2005, §6), validated once.

The mode strings of the rewrite (face texture, mouth texture, blend, tracking preset and
tracker) are defined here, and :class:`RewriteOptions` checks them when it is made, so that
:func:`facetransfer.rewrite_clip.rewrite_frames`, :func:`facetransfer.video_transfer.render_plan`,
:func:`facetransfer.video_transfer.transfer_video`, the demo and ``facetransfer transfer`` share
one definition of what is allowed (and one error message for each).

The tracking presets' names (:data:`~facetransfer.track.presets.SPEED_PRESETS`,
:data:`~facetransfer.track.presets.DEFAULT_SPEED`, :data:`~facetransfer.track.presets.TRACK_METHODS`,
:func:`~facetransfer.track.presets.check_track_method`) are :mod:`facetransfer.track.presets`',
and :class:`~facetransfer.errors.RewriteError` is :mod:`facetransfer.errors`'; both are importable
from here too (every mode of a rewrite in one import).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .errors import RewriteError
from .track.presets import DEFAULT_SPEED, SPEED_PRESETS, TRACK_METHODS, check_track_method

__all__ = [
    "RewriteError",
    "TEXTURE_MODES",
    "MOUTH_MODES",
    "BLEND_MODES",
    "EYE_MODES",
    "JAW_MODES",
    "LIP_MODES",
    "LIP_COLOUR_MODES",
    "SPEED_PRESETS",
    "DEFAULT_SPEED",
    "TRACK_METHODS",
    "RewriteOptions",
    "BlendOptions",
    "check_mode",
    "check_track_method",
]


#: Where the target's face texture comes from: one for the clip or the current frame's.
TEXTURE_MODES = ("constant", "frame")
#: Where the mouth texture comes from: the mouth source's frame at the matched time
#: (``"frame"``) or the performance-driven texture function of §6 (``"function"``).
MOUTH_MODES = ("frame", "function")
#: Ways to put the rendered face into the frame: Pérez et al.'s Poisson solve (exact), a
#: membrane (harmonic-like) correction interpolated by push-pull (fast), or a hard paste.
BLEND_MODES = ("fast", "poisson", "none")
#: Where the eyes of the result come from: the model's lids over an open-eyed target frame, or
#: the target's own eyes through the mesh's eye holes (§6).
EYE_MODES = ("model", "target")
#: Where the chin and jaw skin's texture comes from (with the per-frame face texture): one
#: target frame with the mouth closed (:mod:`facetransfer.jaw`), or each target frame.
JAW_MODES = ("closed", "frame")
#: How the source's lips reach the result (with the source's frame as the mouth texture): with
#: the capture's residual at the lips (:mod:`facetransfer.lips`: the texture read where the
#: detected lips are, the new lips moved by the residual's shape) or as the model fitted them.
LIP_MODES = ("residual", "model")
#: Whose colour the lips of the result take (with a mouth from another clip): the target's
#: lips against its skin (:mod:`facetransfer.lip_colour`) or the source's, as §6 pastes them.
LIP_COLOUR_MODES = ("target", "source")
#: Where the eyes of the result look (with ``eyes="model"``): where the new performance looks
#: (its eyeLook* activations, :mod:`facetransfer.eyeballs`) or where the target looks in each
#: of its own frames.
GAZE_MODES = ("performance", "target")


def check_mode(name: str, value, modes: tuple[str, ...], *, sep: str = ", ") -> None:
    """Raise :class:`RewriteError` ``"{name} must be one of {modes}, got {value!r}"`` unless
    ``value`` is one of ``modes`` (joined by ``sep``; ``sep=None``: the tuple's repr)."""
    if value not in modes:
        allowed = repr(modes) if sep is None else sep.join(modes)
        raise RewriteError(f"{name} must be one of {allowed}, got {value!r}")


@dataclass(frozen=True)
class BlendOptions:
    """How one rendered face goes into its target frame (§6, Fig. 7D-E; Pérez et al. 2003):
    the blend of :func:`facetransfer.rewrite.rewrite_frame`, checked when made.

    Attributes
    ----------
    mode : {"fast", "poisson", "none"}
        :func:`facetransfer.composite.membrane_blend` (fast), Poisson blending
        (:func:`facetransfer.composite.composite_face`, exact sparse solve) or a hard paste.
    feather : float
        Soft-edge radius of the blend in pixels (these pixels, ``erode``'s and
        ``mouth_feather``'s are a face's whose eyes lie up to
        :data:`facetransfer.face_scale.FACE_SPAN` apart; the rewrite grows them with a larger
        face: :meth:`scaled`).
    erode : int
        The blend region is the rendered face mask eroded by this many pixels.
    mouth_feather : float
        Soft-edge width in pixels of the source's mouth inside the face (``mode="fast"``).
        There the mouth takes the face's colours by a smooth gain fitted on the skin around it
        (:func:`facetransfer.mouth.blend_mouth`: per channel on the lips, one gain for the three
        channels on the mouth's inside).
    color_match : bool
        Match the rendered face's colour statistics to the target's before the Poisson blend.

    Raises
    ------
    RewriteError
        An unknown ``mode``.
    """

    mode: str = "fast"
    feather: float = 2.0
    erode: int = 2
    mouth_feather: float = 3.0
    color_match: bool = False

    def __post_init__(self) -> None:
        check_mode("blend", self.mode, BLEND_MODES)

    def scaled(self, scale: float) -> "BlendOptions":
        """These options for a face ``scale`` times the size their pixels are given for
        (:func:`facetransfer.face_scale.face_scale`, which the rewrite applies to every frame):
        ``feather``, ``erode`` (rounded) and ``mouth_feather`` times ``scale``; these options
        themselves at 1."""
        if scale == 1.0:
            return self
        return dataclasses.replace(self, feather=self.feather * scale,
                                   erode=int(round(self.erode * scale)),
                                   mouth_feather=self.mouth_feather * scale)


@dataclass(frozen=True)
class RewriteOptions:
    """How a new performance is rendered into footage (§6), checked when made.

    Attributes
    ----------
    texture : {"frame", "constant"}
        The target's face texture: the current frame's or one for the clip
        (:func:`facetransfer.rewrite_clip.rewrite_frames`).
    mouth : {"frame", "function"} or None
        The mouth texture; None: the job's default
        (:func:`facetransfer.texture.face.default_mouth_mode`).
    blend : {"fast", "poisson", "none"}
        :func:`facetransfer.composite.membrane_blend`, Poisson blending or a hard paste.
    feather : float
        Soft-edge radius of the blend in pixels.
    erode : int
        The blend region is the rendered face mask eroded by this many pixels.
    speed : {"fast", "balanced", "quality"}
        Tracking preset of the videos tracked now.
    track_method : {"auto", "capture", "flow", "landmarks"}
        The tracker of the videos tracked now.
    eyes : {"model", "target"}
        ``"model"``: the eye holes closed and the lids, eyes and brows of the new performance
        rendered with an open-eyed target frame's texture (:mod:`facetransfer.eyes`), so the
        new performance's blinks show; ``"target"``: the holes left open and the target's own
        eyes showing through them, as in the paper (§6).
    jaw : {"closed", "frame"}
        ``"closed"``: the chin and jaw region textured from one target frame with the mouth
        closed (:mod:`facetransfer.jaw`), so the target's own mouth opening does not show
        in the result; ``"frame"``: from each target frame like the rest of the face. Only
        with ``texture="frame"``.
    lips : {"residual", "model"}
        ``"residual"``: the source's lips beyond what the model's shapes fit, from the
        detections the capture kept (:mod:`facetransfer.lips`): the mouth texture read where
        the source's lips are detected and the new face's lips moved by the fit's residual;
        a source track without detections (or ``"model"``) renders the lips as fitted. Only
        with the source's frame as the mouth texture (``mouth="frame"``).
    lip_colour : {"target", "source"}
        ``"target"``: the source's lips take the target's lip colour (its lips against its
        skin, :mod:`facetransfer.lip_colour`), so a target's lipstick stays; ``"source"``:
        the source's lips keep their own colour against the skin (§6). Only with the
        source's frame as the mouth texture (``mouth="frame"``).
    gaze : {"performance", "target"}
        ``"performance"``: the eyes look where the new performance looks (its eyeLook*
        activations turn the open-eyed frame's eyeballs, :mod:`facetransfer.eyeballs`);
        ``"target"``: where the target looks in each of its own frames (eye contact kept).
        Only with ``eyes="model"`` and tracks with ARKit blendshapes.

    Raises
    ------
    RewriteError
        An unknown mode string, a negative ``feather`` or ``erode``.
    """

    texture: str = "frame"
    mouth: str | None = None
    blend: str = "fast"
    feather: float = 2.0
    erode: int = 2
    speed: str = DEFAULT_SPEED
    track_method: str = "auto"
    eyes: str = "model"
    jaw: str = "closed"
    lips: str = "residual"
    lip_colour: str = "target"
    gaze: str = "performance"

    def __post_init__(self) -> None:
        check_mode("texture", self.texture, TEXTURE_MODES, sep=None)
        if self.mouth is not None:
            check_mode("mouth", self.mouth, MOUTH_MODES)
        check_mode("blend", self.blend, BLEND_MODES)
        check_mode("speed", self.speed, SPEED_PRESETS)
        check_track_method(self.track_method)
        check_mode("eyes", self.eyes, EYE_MODES)
        check_mode("jaw", self.jaw, JAW_MODES)
        check_mode("lips", self.lips, LIP_MODES)
        check_mode("lip_colour", self.lip_colour, LIP_COLOUR_MODES)
        check_mode("gaze", self.gaze, GAZE_MODES)
        if not self.feather >= 0:
            raise RewriteError(f"feather must be >= 0 pixels, got {self.feather!r}")
        if int(self.erode) != self.erode or self.erode < 0:
            raise RewriteError(f"erode must be an integer >= 0, got {self.erode!r}")

    @property
    def blending(self) -> BlendOptions:
        """The blend of each frame (:attr:`blend`, :attr:`feather`, :attr:`erode`)."""
        return BlendOptions(self.blend, self.feather, self.erode)

    def with_(self, **changes) -> "RewriteOptions":
        """These options with the given attributes replaced (None values are ignored);
        validated again."""
        changes = {k: v for k, v in changes.items() if v is not None}
        return dataclasses.replace(self, **changes) if changes else self
