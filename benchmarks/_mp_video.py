"""MediaPipe Face Landmarker in VIDEO running mode over a whole clip (the peer of ``bench_capture``).

Library use: :func:`run_landmarker` (478 points in pixels and the 52 ARKit blendshapes per frame),
:func:`cached_landmarker` (the same, cached by the clip's content). As a script it is the peer
process of the speed benchmark: it decodes the clip (OpenCV), runs the landmarker with
blendshapes on every frame and writes the points to an ``.npz``::

    python benchmarks/_mp_video.py CLIP.mp4 OUT.npz
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


#: MediaPipe / TensorFlow Lite / absl lines written straight to file descriptor 2.
_NATIVE_LOG = re.compile(r"^([WIEF]\d{4} |WARNING: Logging before InitGoogle|INFO: Created TensorFlow)")


@contextlib.contextmanager
def filtered_stderr(enabled: bool = True):
    """Drop MediaPipe's native log lines (they bypass Python and ``GLOG_minloglevel``) from
    file descriptor 2 inside the block; every other line is written out when it ends."""
    if not enabled:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            for line in tmp.read().decode(errors="replace").splitlines(keepends=True):
                if not _NATIVE_LOG.match(line):
                    sys.stderr.write(line)
            sys.stderr.flush()


def _task_path() -> Path:
    from facetransfer import assets

    return Path(assets.asset_file("face_landmarker"))


def _frames(video):
    """RGB frames of a path (decoded lazily with OpenCV) or of an array, and the fps."""
    import cv2

    if not isinstance(video, (str, os.PathLike)):
        return iter(video), 30.0
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise ValueError(f"cannot open video {video}")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0

    def gen():
        try:
            while True:
                ok, bgr = cap.read()
                if not ok:
                    return
                yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        finally:
            cap.release()

    return gen(), float(fps)


def run_landmarker(video, *, blendshapes: bool = True, task: str | os.PathLike | None = None,
                   fps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Run Face Landmarker (Tasks API, VIDEO mode, one face) over a clip.

    Parameters
    ----------
    video : path-like or iterable of (H, W, 3) uint8 RGB frames
    fps : float, optional
        The frames' rate (their timestamps); default a file's own, 30 for frames.

    Returns
    -------
    points : (F, 478, 2) float64
        Pixels (centres at integers), NaN where no face was found.
    shapes : (F, 52) float64
        Blendshape scores in ``facetransfer.arkit.ARKIT_NAMES`` order (``tongueOut`` 0), NaN
        where no face was found.
    """
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    from facetransfer.arkit import ARKIT_NAMES

    col = {n: i for i, n in enumerate(ARKIT_NAMES)}
    opts = vision.FaceLandmarkerOptions(
        base_options=BaseOptions(model_asset_path=str(task or _task_path())),
        running_mode=vision.RunningMode.VIDEO, num_faces=1,
        output_face_blendshapes=blendshapes)
    frames, own_fps = _frames(video)
    fps = own_fps if fps is None else float(fps)
    pts, shp = [], []
    with vision.FaceLandmarker.create_from_options(opts) as lm:
        for i, f in enumerate(frames):
            f = np.ascontiguousarray(f, dtype=np.uint8)
            res = lm.detect_for_video(mp.Image(image_format=mp.ImageFormat.SRGB, data=f),
                                      int(round(i * 1000.0 / fps)))
            H, W = f.shape[:2]
            p, s = np.full((478, 2), np.nan), np.full(len(ARKIT_NAMES), np.nan)
            if res.face_landmarks:
                p = np.array([[q.x * W - 0.5, q.y * H - 0.5] for q in res.face_landmarks[0]])
                if blendshapes and res.face_blendshapes:
                    s[:] = 0.0
                    for c in res.face_blendshapes[0]:
                        if c.category_name in col:
                            s[col[c.category_name]] = c.score
            pts.append(p)
            shp.append(s)
    return np.array(pts), np.array(shp)


def _content_key(path: Path) -> str:
    import mediapipe

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read())
    h.update(mediapipe.__version__.encode())
    h.update(str(_task_path().stat().st_size).encode())
    return h.hexdigest()[:16]


def shown_landmarker(video: Path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`run_landmarker` on a clip file seen at its shown shape: a clip whose pixels are
    not square (its sample aspect ratio) resampled to square pixels first (OpenCV, its width
    ``round(W sar)``, as the tracker sees it); the points told in the stored pixels again
    (``x = (x_shown + 0.5) / a - 0.5``)."""
    from facetransfer.io.video import video_info

    info = video_info(video)
    if tuple(info.sar) == (1, 1):
        return run_landmarker(video)
    W = info.size[0]
    w = max(1, round(W * info.sar[0] / info.sar[1]))
    pts, shp = run_landmarker(shown_frames(_frames(video)[0], info.sar), fps=info.fps)
    pts[..., 0] = (pts[..., 0] + 0.5) * (W / w) - 0.5
    return pts, shp


def shown_frames(frames, sar: tuple[int, int]):
    """``frames`` resampled to square pixels (their width ``round(W sar)``; OpenCV, area
    averaging when narrower, linear when wider), as the tracker sees them; written here, not
    taken from ``facetransfer``, so that an older tree's results are judged alike."""
    import cv2

    for f in frames:
        H, W = f.shape[:2]
        w = max(1, round(W * sar[0] / sar[1]))
        yield cv2.resize(np.ascontiguousarray(f), (w, H),
                         interpolation=cv2.INTER_AREA if w < W else cv2.INTER_LINEAR)


def cached_landmarker(video: Path, cache: Path, *, shown: bool = False
                      ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`run_landmarker` of a clip file, cached in ``cache`` by the clip's bytes and the
    MediaPipe version; with ``shown``, :func:`shown_landmarker` (a clip of square pixels: the
    same)."""
    from facetransfer.io.atomic import atomic_path
    from facetransfer.io.video import video_info

    video = Path(video)
    shown = shown and tuple(video_info(video).sar) != (1, 1)
    tail = "-shown" if shown else ""
    path = cache / "mediapipe" / f"{video.stem}-{_content_key(video)}{tail}.npz"
    if path.is_file():
        with np.load(path) as z:
            return z["points"], z["blendshapes"]
    pts, shp = shown_landmarker(video) if shown else run_landmarker(video)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, points=pts, blendshapes=shp)
    return pts, shp


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: _mp_video.py CLIP OUT.npz", file=sys.stderr)
        return 2
    with filtered_stderr():
        pts, shp = run_landmarker(argv[0])
    np.savez(argv[1], points=pts, blendshapes=shp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
