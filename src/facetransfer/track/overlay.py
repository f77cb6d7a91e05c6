"""Draw a tracked face on its frames so a person can judge the fit at a glance."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import ShapeError

__all__ = ["IBUG_CONTOURS", "mesh_edges", "draw_overlay", "overlay_frames", "write_overlay"]

#: The iBUG-68 points drawn as lines, ``(first, stop, closed)``: the jaw, the brows, the nose's
#: bridge and base, the eyes, the outer and inner lips. A lid or a lip read as a line is judged
#: against the picture at a glance, where 68 dots on a mesh are not.
IBUG_CONTOURS = ((0, 17, False), (17, 22, False), (22, 27, False), (27, 31, False),
                 (31, 36, False), (36, 42, True), (42, 48, True), (48, 60, True),
                 (60, 68, True))


def mesh_edges(faces: np.ndarray, *, stride: int = 1) -> np.ndarray:
    """Unique undirected edges of a triangle mesh, (E, 2) int64 (every ``stride``-th kept)."""
    F = np.asarray(faces, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3:
        raise ShapeError(f"faces must be (n, 3), got {F.shape}")
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    return E[:: max(int(stride), 1)]


def draw_overlay(frame: np.ndarray, vertices2d: np.ndarray, edges: np.ndarray,
                 landmarks2d: np.ndarray | None = None, *, visible: np.ndarray | None = None,
                 color=(80, 220, 255), landmark_color=(255, 60, 60), alpha: float = 0.22,
                 lost: bool = False, text: str | None = None) -> np.ndarray:
    """Wireframe of the fitted mesh (faint) and its 68 landmarks as contours
    (:data:`IBUG_CONTOURS`) drawn over a frame.

    Parameters
    ----------
    frame : (H, W, 3) uint8 RGB
    vertices2d : (n, 2) float
        Projected mesh vertices (pixels).
    edges : (E, 2) int
        From :func:`mesh_edges`.
    landmarks2d : (68, 2) float, optional
    visible : (n,) bool, optional
        Only edges between visible vertices are drawn.
    lost : bool
        Draw in red and label the frame as lost.
    text : str, optional
        A caption in the top-left corner.

    Returns
    -------
    (H, W, 3) uint8
    """
    img = np.ascontiguousarray(frame, dtype=np.uint8).copy()
    P = np.asarray(vertices2d, dtype=np.float64)
    E = np.asarray(edges, dtype=np.int64)
    if visible is not None:
        E = E[visible[E[:, 0]] & visible[E[:, 1]]]
    sh = 4  # fixed-point bits for sub-pixel line positions
    pts = np.rint(P * (1 << sh)).astype(np.int32)
    lines = pts[E].reshape(-1, 2, 2)
    ok = np.all(np.abs(lines) < (1 << 28), axis=(1, 2))
    layer = img.copy()
    col = (255, 40, 40) if lost else color
    cv2.polylines(layer, list(lines[ok]), False, col, 1, cv2.LINE_AA, sh)
    img = cv2.addWeighted(layer, alpha, img, 1 - alpha, 0)
    if landmarks2d is not None:
        L = np.asarray(landmarks2d, dtype=np.float64)
        for a, b, closed in IBUG_CONTOURS:
            if np.all(np.isfinite(L[a:b])):
                cv2.polylines(img, [np.rint(L[a:b] * 16).astype(np.int32)], closed,
                              landmark_color, 1, cv2.LINE_AA, 4)
    label = ("LOST " if lost else "") + (text or "")
    if label:
        cv2.putText(img, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2,
                    cv2.LINE_AA)
        cv2.putText(img, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def overlay_frames(frames, track, model, *, edge_stride: int = 1, visibility: bool = True):
    """Yield frames with the tracked mesh and landmarks drawn (see :func:`draw_overlay`).

    Parameters
    ----------
    frames : iterable of (H, W, 3) uint8
        The tracked video's frames, in order.
    track : Track
    model : MultilinearModel
        The model the track was made with.
    """
    from ..render import vertex_visibility

    E = mesh_edges(model.faces, stride=edge_stride)
    for i, fr in enumerate(frames):
        if i >= track.n_frames:
            break
        V = model.synthesize(track.weights_at(i))
        cam = track.camera(i)
        P = cam.project(V)
        vis = None
        if visibility:
            try:
                vis = vertex_visibility(V, model.faces, cam, track.frame_size)
            except ValueError:
                vis = None
        yield draw_overlay(fr, P, E, track.landmarks2d[i], visible=vis,
                           lost=bool(track.lost[i]),
                           text=f"{i}  conf {track.confidence[i]:.2f}")


def write_overlay(video, track, model, path, *, progress=None, overwrite: bool = True,
                  options=None):
    """Write the overlay video of a track, atomically (:class:`~facetransfer.io.video.VideoWriter`).

    Parameters
    ----------
    video : path-like
        The tracked video (must match the track's frame count and size).
    track : Track
    model : MultilinearModel
    path : path-like
        Output video (``.mp4``...) or image sequence (``frames/%05d.png``).
    progress : callable(int), optional
        Called with 1 per frame written.
    options : VideoOptions, optional
        Codec and CRF (default H.264, CRF 18); pixel aspect ratio and colour tags as
        ``video``'s (:func:`~facetransfer.io.video_like.like_video`).
    """
    from ..io.video import VideoWriter, iter_frames
    from ..io.video_like import like_video

    with VideoWriter(path, track.fps, track.frame_size, overwrite=overwrite,
                     options=like_video(options, video)) as w:
        for img in overlay_frames(iter_frames(video, stop=track.n_frames), track, model):
            w.write(img)
            if progress is not None:
                progress(1)
    return path
