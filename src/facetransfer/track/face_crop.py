"""Small faces in large frames: the face found in tiles of the frame and followed in a crop.

Face Landmarker looks for a face in the whole frame shrunk to its detector's 128x128 input, so
a face under about a tenth of the frame's height (a medium-wide shot in HD: the actor's face 150
pixels high in 1080 rows) is never found, and the capture says "no face found". The landmark
model itself, once given the face's region, reads it from the full-resolution frame.

:class:`FollowingLandmarker` is the detector of the capture's detections
(:func:`facetransfer.track.detect.detect_clip`): each frame goes to Face Landmarker whole
while that finds the face. Where it does not, and the frame is large enough to hold a
face too small for the whole-frame search (:func:`search_tiles` gives it tiles), the
frame is searched tile by tile (overlapping squares of half its shorter side, then a quarter),
and the face found is then followed in a square crop about it (:func:`crop_about`: three times
the face's size, moved with it every frame) by a second landmarker in video mode, the points
shifted back to the frame. When the face grows past :data:`WHOLE_FRAME_SHARE` of the frame, or
the crop loses it, the whole frame is tried again. Footage whose face the whole-frame detector
finds is detected exactly as by that detector alone.

A picture (a clip of one frame: a photo, ``track PHOTO``, ``transfer --target PHOTO``) is
looked at :data:`STILL_LOOKS` times, the last look kept (``still=True``): Face Landmarker reads
a frame's points in a region its face detector gives on the first frame it sees, and from the
next frame on in the region its own points gave (its video mode), which lies better on a face
turned or in glasses. Measured (``benchmarks/bench_eye_openings.py``): on ``stills/breakingbad``
(the head turned ~50°, glasses) the first look's contour of the near eye lay on the lower lid,
9.3 px (16 % of the eye's width) from the human points, the second's on the eye, 2.0 px.

Several faces (an interview, a two-shot): Face Landmarker follows one face, whichever it found
first, and may take another after a loss, as may the second detection process that starts in
the clip's middle (:mod:`facetransfer.track.video_detect`), so a track could change person. The
face followed is the *subject*, the face first found: when the whole-frame landmarker's face is
farther from the subject's last place than its own size (:func:`moved_away`), the frame's faces
are counted (an IMAGE-mode landmarker finding up to :data:`MOST_FACES`, made only then); of
several, the nearest to that place is the subject (:func:`choose_subject`), followed in a crop
from then on. A second detection process that starts on another face is detected again
(:func:`facetransfer.track.video_detect.other_face`). Where the subject is hidden (turned
away, behind something) while another person stays in view, the one face found far from the
subject's last place is that person's when the shot holds several people (counted then, or in
the frame before) and did not cut there (:data:`CUT_CHANGE`): those frames have no face, and
the subject is followed again when it shows (:meth:`FollowingLandmarker._other_person`).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import TrackError
from .detect import VideoLandmarker
from .init import MediaPipeDetector

__all__ = ["WHOLE_FRAME_SHARE", "CROP_FACES", "SEARCH_EVERY", "SEARCH_SLOWER", "MOST_FACES",
           "CUT_CHANGE", "STILL_LOOKS",
           "search_tiles", "face_box", "choose_subject", "moved_away",
           "crop_about", "FACE_PLACES", "face_place", "subject_point", "FacePoint",
           "FaceNotAtPoint", "near_point", "FollowingLandmarker"]

#: A face found in a crop whose size (its points' larger extent) passes this share of the
#: frame's shorter side goes back to the whole-frame detector, which finds faces this large.
WHOLE_FRAME_SHARE = 0.3
#: The crop's side in face sizes (the landmark model's region is ~1.5 face sizes; the rest
#: leaves room for the motion between two frames).
CROP_FACES = 3.0
#: In a run of frames without a face, the tiles are searched in one frame of this many (a
#: search of a 1080p frame runs the detector on up to 119 tiles), one of five times as many
#: after :data:`SEARCH_SLOWER` frames: a clip whose face is away for a while stays cheap.
SEARCH_EVERY = 5
SEARCH_SLOWER = 50
#: The most faces the IMAGE-mode landmarker finds (the tiles searched, the faces counted).
MOST_FACES = 4
#: A picture change (:func:`facetransfer.track.detect.picture_change`, levels) from which a
#: frame is another shot's for the subject's rule: within the data folder's clips at most 12.2,
#: at edited cuts 36-72 (:mod:`facetransfer.track.shots`).
CUT_CHANGE = 25.0
#: How often a picture is shown to the landmarker (:class:`FollowingLandmarker`'s ``still``):
#: the second look reads it in the region of the first look's own points (module notes).
STILL_LOOKS = 2
#: The smallest tile side searched, pixels (the detector's input is 128; a face in a smaller
#: tile is too small for the landmark model too).
_MIN_TILE = 192


def search_tiles(size: tuple[int, int]) -> list[tuple[int, int, int]]:
    """Square tiles ``(x0, y0, side)`` that cover a frame of ``size`` (W, H) at two scales,
    half and a quarter of its shorter side (overlapping by half a tile), the coarser first;
    none for a frame whose shorter side is under two of the smallest tiles (the whole-frame
    search already sees every face the landmark model can read there)."""
    W, H = (int(v) for v in size)
    tiles = []
    for share in (0.5, 0.25):
        side = int(min(W, H) * share)
        if side < _MIN_TILE:
            break
        step = side // 2
        xs = list(range(0, max(W - side, 0) + 1, step))
        ys = list(range(0, max(H - side, 0) + 1, step))
        if xs[-1] != W - side:
            xs.append(W - side)
        if ys[-1] != H - side:
            ys.append(H - side)
        tiles += [(x, y, side) for y in ys for x in xs]
    return tiles


def face_box(points: np.ndarray) -> tuple[float, float, float]:
    """``(cx, cy, size)``: the centre of a face's points (N, 2) and their larger extent."""
    P = np.asarray(points, dtype=np.float64)
    lo, hi = np.nanmin(P, axis=0), np.nanmax(P, axis=0)
    return float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2), float(max(hi - lo))


def crop_about(box: tuple[float, float, float], size: tuple[int, int]) -> tuple[int, int, int]:
    """The square crop ``(x0, y0, side)`` of :data:`CROP_FACES` face sizes centred on ``box``
    (:func:`face_box`), kept inside a frame of ``size`` (W, H) (moved in, never cut)."""
    W, H = (int(v) for v in size)
    cx, cy, s = box
    side = int(min(max(CROP_FACES * s, _MIN_TILE), W, H))
    x0 = int(np.clip(round(cx - side / 2), 0, W - side))
    y0 = int(np.clip(round(cy - side / 2), 0, H - side))
    return x0, y0, side


def choose_subject(boxes: list[tuple[float, float, float]],
                   last: tuple[float, float, float] | None) -> int:
    """Which of several faces' boxes (:func:`face_box`) is the subject: the nearest to its
    ``last`` box, or without one the largest."""
    if last is None:
        return int(np.argmax([b[2] for b in boxes]))
    return int(np.argmin([np.hypot(b[0] - last[0], b[1] - last[1]) for b in boxes]))


def moved_away(box: tuple[float, float, float], last: tuple[float, float, float]) -> bool:
    """Whether a face's box is not where the subject's ``last`` box was: farther than that
    face's size (a frame's motion is a fraction of it)."""
    return bool(np.hypot(box[0] - last[0], box[1] - last[1]) > last[2])


#: Where ``track --face`` may say the subject is, as a share of the frame's width and height.
FACE_PLACES = {"left": (0.0, 0.5), "right": (1.0, 0.5), "centre": (0.5, 0.5),
               "center": (0.5, 0.5)}


def face_place(text: str, what: str = "--face") -> tuple[str, tuple[float, float]]:
    """What ``--face`` says, before any frame is seen: ``("share", (fx, fy))`` for ``"left"``,
    ``"right"``, ``"centre"`` (:data:`FACE_PLACES`), ``("pixels", (x, y))`` for ``"X,Y"``.

    Raises
    ------
    TrackError
        Anything else (a batch manifest's cell is checked so before any clip runs); the
        message names the option or cell ``what``.
    """
    said = str(text).strip().lower()
    if said in FACE_PLACES:
        return "share", FACE_PLACES[said]
    try:
        x, y = (float(v) for v in said.split(","))
    except ValueError:
        x = y = float("nan")
    if not (x >= 0 and y >= 0 and np.isfinite(x + y)):
        raise TrackError(f"{what} must be left, right, centre or pixels X,Y, got {text!r}")
    return "pixels", (x, y)


class FacePoint(tuple):
    """A point ``(x, y, 0.0)`` (a box of no size, :func:`face_box`) where ``--face`` said the
    subject is; ``said``: the pixels ``"X,Y"`` as given, "" for a place (``left``, ...). A
    face must be found at or near pixels said (:meth:`FollowingLandmarker._refuse_far`)."""

    said: str

    def __new__(cls, x: float, y: float, said: str = "") -> "FacePoint":
        point = super().__new__(cls, (float(x), float(y), 0.0))
        point.said = str(said)
        return point

    def __getnewargs__(self):
        return self[0], self[1], self.said


class FaceNotAtPoint(TrackError):
    """No face found at or near the pixels ``--face`` said (:func:`near_point`), only others:
    ``said`` the point as given, ``centres`` the faces' centres (the pixels the detector was
    shown). :func:`facetransfer.track.video_detect.detect_video` names the file."""

    def __init__(self, said: str, centres: list[tuple[float, float]]) -> None:
        self.said, self.centres = said, centres
        super().__init__(self.line("the frame"))

    def line(self, where: str, aspect: float = 1.0) -> str:
        """The refusal, ``where`` the file (the faces' columns in its stored pixels, of
        ``aspect``, :func:`facetransfer.track.aspect.to_stored_x`)."""
        from .aspect import to_stored_x

        faces = ", ".join(f"({float(to_stored_x(x, aspect)):.0f}, {y:.0f})"
                          for x, y in self.centres)
        many = "a face" if len(self.centres) == 1 else f"{len(self.centres)} faces"
        return (f"no face found at or near the point {self.said} in {where}: {many} found, "
                f"centred at {faces} (pixels X,Y); give a point on the face to follow")


def near_point(point, box: tuple[float, float, float]) -> bool:
    """Whether a face's box (:func:`face_box`) lies at or near the ``point`` (x, y): the point
    within the face's size (its points' larger extent) of its centre, inside the face's box
    grown by half its size on each side or about as near: the box not :func:`moved_away` from
    a box of no size at the point, as :meth:`FollowingLandmarker._at_point` asks it."""
    return not moved_away((point[0], point[1], 0.0), box)


def subject_point(text: str, size: tuple[int, int], what: str = "--face") -> FacePoint:
    """The subject of ``track --face`` in a frame of ``size`` (W, H): ``"left"``, ``"right"``,
    ``"centre"`` or pixels ``"X,Y"`` (:func:`face_place`), as a box of no size
    (:func:`face_box`, a :class:`FacePoint`): of several faces, the nearest is followed from
    the first frame on; pixels said must lie at or near a face found (:func:`near_point`:
    else :class:`FaceNotAtPoint` where the face is chosen).

    Raises
    ------
    TrackError
        Anything else, or a point outside the frame (the message names ``what``).
    """
    W, H = (float(v) for v in size)
    try:
        kind, (x, y) = face_place(text)
    except TrackError:
        kind, x, y = "pixels", -1.0, -1.0
    if kind == "share":
        return FacePoint(x * (W - 1), y * (H - 1))
    if not (0 <= x < W and 0 <= y < H):
        raise TrackError(f"{what} must be left, right, centre or pixels X,Y inside the "
                         f"{int(W)}x{int(H)} frame, got {text!r}")
    return FacePoint(x, y, said=f"{x:g},{y:g}")


class FollowingLandmarker:
    """Face Landmarker on the whole frame, and where that finds no face, in tiles and then in a
    crop that follows the face (see the module notes). Has the detector interface of
    :func:`facetransfer.track.detect.detect_clip`: ``detect_scored(frame)`` in frame order,
    ``warmup_frames``, ``close()``.

    Parameters
    ----------
    fps : float
        The clip's rate (the video-mode landmarkers' timestamps).
    blendshapes : bool
        Also return the 52 blendshape scores.
    model_path : path-like, optional
    subject : (cx, cy, size), optional
        Where the face to follow was last (:func:`face_box`), or a point (size 0,
        :func:`subject_point`): of several faces, the nearest to it is followed; pixels said
        (a :class:`FacePoint`'s ``said``) with no face at or near them where the face is chosen
        (the first frame where one is found): :class:`FaceNotAtPoint`.
    still : bool
        The clip is one picture: a frame whose face is found is looked at again
        (:data:`STILL_LOOKS` in all), the last look's points kept (module notes).
    """

    warmup_frames = VideoLandmarker.warmup_frames

    def __init__(self, *, fps: float = 30.0, blendshapes: bool = True,
                 model_path: str | os.PathLike | None = None, subject=None,
                 still: bool = False) -> None:
        self.still = bool(still)
        self._whole = VideoLandmarker(model_path, fps=fps, blendshapes=blendshapes)
        self._args = (model_path, float(fps), bool(blendshapes))
        self._crop_lm = None            # created when first needed: most clips never do
        self._search_lm = None          # IMAGE mode, up to MOST_FACES: tiles and counting
        self.crop: tuple[int, int, int] | None = None
        self.last = None if subject is None else tuple(float(v) for v in subject)
        self._said = getattr(subject, "said", "")   # pixels said: a face must lie there
        self.several = False            # several faces seen: the subject kept in a crop
        self._missed = 0                # frames since the last face (the search's rhythm)
        self._frame = 0                 # frames seen: the landmarkers' clock
        self._prev = None               # the frame before (a hidden subject's, a cut's)
        self._hidden = False            # this frame: only another person's face is seen

    def detect_scored(self, frame: np.ndarray):
        """``(points (478, 2) in the frame's pixels, scores (52,))`` or ``(None, None)``; of
        a ``still``, the last of its looks that found the face."""
        found = self._look(frame)
        for _ in range(STILL_LOOKS - 1 if self.still and found[0] is not None else 0):
            again = self._look(frame)           # the landmarker's region: its own points
            found = again if again[0] is not None else found
        return found

    def _look(self, frame: np.ndarray):
        """One look at ``frame`` (the landmarkers' clock moves on a frame)."""
        found = self._in_crop(frame) if self.crop is not None else (None, None)
        self._hidden = False
        if found[0] is None:
            found = self._whole.at_least(self._frame).detect_scored(frame)
            if found[0] is not None and self.last is not None and \
                    moved_away(face_box(found[0]), self.last):
                found = self._subject(frame, found)
        if found[0] is None and not self._hidden:
            found = self._searched(frame)
        self._missed = 0 if found[0] is not None else self._missed + 1
        if found[0] is not None:
            self.last = face_box(found[0])
        self._frame += 1
        self._prev = frame
        return found

    def skip(self, frame: np.ndarray) -> None:
        """A frame not shown (:func:`facetransfer.track.detect.detect_clip`'s ``every``): the
        clocks move on; a search counts it as a frame without a face only when the last frame
        had none (the caller skips only after a face)."""
        self._frame += 1
        self._prev = frame

    def _subject(self, frame: np.ndarray, found):
        """``found`` (the whole frame's face) where it is the only face or the subject
        (:func:`choose_subject`), else the subject followed in a crop; none where the one face
        is another person's, the subject hidden (:meth:`_other_person`)."""
        boxes = [face_box(q) for q in self._search_landmarker().detect_every(frame)]
        if len(boxes) == 1 and self._other_person(frame):
            self._hidden = True
            return None, None
        said = self._at_point(frame, boxes) if self.last[2] == 0 else None
        if said is not None:
            return said
        if self.last[2] == 0:
            self._refuse_far([*boxes, face_box(found[0])])
        if len(boxes) < 2:
            return found
        self.several = True
        box = boxes[choose_subject(boxes, self.last)]
        if not moved_away(face_box(found[0]), box):     # the whole frame's face is the subject
            return found
        H, W = frame.shape[:2]
        self.crop = crop_about(box, (W, H))
        return self._in_crop(frame)

    def _at_point(self, frame: np.ndarray, boxes: list):
        """The face at the point ``--face`` said, before any face is followed, where none of
        the whole frame's ``boxes`` lies there: searched in the tiles about the point (finest
        first), and kept where it is nearer the point than every one of them; else None.

        A face too small for the whole-frame search beside a larger one (walk53: a face 60
        pixels tall pasted into a 1080p photo of two people, ``--face`` on it) was passed over
        for the large one: the point lay in no face the whole frame showed, and where that
        showed none, the tiles' search took the first tile's face, wherever it was."""
        x, y, _ = self.last
        if any(not moved_away((x, y, 0.0), b) for b in boxes):
            return None                                   # a face found lies at the point
        H, W = frame.shape[:2]
        for x0, y0, side in sorted(search_tiles((W, H)), key=lambda t: t[2]):
            if not (x0 <= x < x0 + side and y0 <= y < y0 + side):
                continue
            q, _ = self._search_landmarker().detect_scored(
                np.ascontiguousarray(frame[y0:y0 + side, x0:x0 + side]))
            if q is None:
                continue
            box = face_box(q + (x0, y0))
            if choose_subject([*boxes, box], self.last) != len(boxes) or \
                    (self._said and not near_point(self.last, box)):
                continue              # a face the whole frame shows is nearer, or none is here
            self.several = True
            self.crop = crop_about(box, (W, H))
            found = self._in_crop(frame)
            if found[0] is not None:
                return found
        return None

    def _other_person(self, frame: np.ndarray) -> bool:
        """Whether the one face in ``frame``, far from the subject's last place, is another
        person's: the shot holds several people (counted now, or in the frame before, where
        the subject was) and did not cut here (:data:`CUT_CHANGE`: after a cut the face found
        is followed, as at a clip's start)."""
        import cv2

        from .detect import picture_change

        if self._prev is None:
            return False
        grey = [cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY)
                for f in (self._prev, frame)]
        if picture_change(*grey) >= CUT_CHANGE:
            self.several = False
            return False
        if not self.several:
            self.several = len(self._search_landmarker().detect_every(self._prev)) >= 2
        return self.several

    def _in_crop(self, frame: np.ndarray):
        """The face in the crop (its points in the frame's pixels), the crop moved with it; the
        crop given up when it loses the face or the face has grown large."""
        x0, y0, side = self.crop
        q, scores = self._crop_landmarker().detect_scored(
            np.ascontiguousarray(frame[y0:y0 + side, x0:x0 + side]))
        if q is None:
            self.crop = None
            return None, None
        q = q + (x0, y0)
        box = face_box(q)
        H, W = frame.shape[:2]
        large = box[2] > WHOLE_FRAME_SHARE * min(W, H) and not self.several
        self.crop = None if large else crop_about(box, (W, H))
        return q, scores

    def _searched(self, frame: np.ndarray):
        """The face in the first tile that shows one which its crop confirms (a search in one
        frame of :data:`SEARCH_EVERY` without a face); its crop then followed; none where it is
        another person's, the subject hidden (:meth:`_other_person`).

        A tile's detector also finds faces that are none (an animal painted on the wall behind
        the speaker of ``stills/einstein.jpg``, 43 pixels); the landmark model in the crop
        about it then finds nothing, and the search goes on to the next tiles (it stopped
        there: the speaker's face was never searched for, in that frame nor in any later one).
        """
        H, W = frame.shape[:2]
        tiles = search_tiles((W, H))
        every = SEARCH_EVERY * (1 if self._missed < SEARCH_SLOWER else 5)
        if not tiles or self._missed % every:
            return None, None
        said = self._at_point(frame, []) if self.last is not None and self.last[2] == 0 \
            else None
        if said is not None:
            return said
        for x0, y0, side in tiles:
            q, _ = self._search_landmarker().detect_scored(
                np.ascontiguousarray(frame[y0:y0 + side, x0:x0 + side]))
            if q is not None:
                box = face_box(q + (x0, y0))
                if self.last is not None and moved_away(box, self.last) and \
                        self._other_person(frame):
                    return None, None                  # the subject hidden
                self.crop = crop_about(box, (W, H))
                found = self._in_crop(frame)
                if found[0] is not None:
                    if self.last is not None and self.last[2] == 0:
                        self._refuse_far([face_box(found[0])])
                    return found
        return None, None

    def _refuse_far(self, boxes: list) -> None:
        """:class:`FaceNotAtPoint` where ``--face`` said pixels (:class:`FacePoint`) and no
        face of ``boxes`` (those found where the subject is chosen, the tiles about the point
        searched too, :meth:`_at_point`) lies at or near them (:func:`near_point`).

        Before, such a point (one on the background of ``stills/breakingbad.jpg``, beside two
        people) silently followed the face nearest it, or the only face, wherever it was."""
        if not self._said or any(near_point(self.last, b) for b in boxes):
            return
        kept: list = []                 # a face counted and found by the whole frame: once
        for b in boxes:
            if all(np.hypot(b[0] - k[0], b[1] - k[1]) > min(b[2], k[2]) / 2 for k in kept):
                kept.append(b)
        raise FaceNotAtPoint(self._said, [(b[0], b[1]) for b in kept])

    def _crop_landmarker(self) -> VideoLandmarker:
        if self._crop_lm is None:
            path, fps, blendshapes = self._args
            self._crop_lm = VideoLandmarker(path, fps=fps, blendshapes=blendshapes)
        return self._crop_lm.at_least(self._frame)

    def _search_landmarker(self) -> MediaPipeDetector:
        if self._search_lm is None:
            self._search_lm = MediaPipeDetector(self._args[0], faces=MOST_FACES)
        return self._search_lm

    def close(self) -> None:
        for lm in (self._whole, self._crop_lm, self._search_lm):
            if lm is not None:
                lm.close()
        self._crop_lm = self._search_lm = None

    def __enter__(self) -> "FollowingLandmarker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
