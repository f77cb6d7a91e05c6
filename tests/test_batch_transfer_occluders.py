"""``batch transfer`` onto a target whose track records a covered mouth (a track of ``track
--occluders`` or ``batch track --occluders``, a pairs manifest's ``target_track``): the result and
its matte are those ``transfer --target-track`` writes, to the bit, the occluder kept in front of
the new face; a row whose target track was not tested paints the new mouth over it. On real
footage: ``driving_d6``'s first frames with occl54's hand-coloured box over the mouth."""

from __future__ import annotations

import csv
import dataclasses
import functools
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.batch import cluster as batch_cluster  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.video import read_video, write_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

#: Frames of the clip, and those with the box over the mouth.
N_FRAMES, COVERED = 24, range(8, 16)
#: A hand's colour (occl54's box, tests/test_occlusion.py's).
HAND = (195, 140, 100)
#: Face Landmarker's outer lip points (of its 478).
LIPS = [61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40,
        185]


def _cli(*argv) -> int:
    return main([str(a) for a in argv])


def _box(lips: np.ndarray) -> tuple[int, int, int, int]:
    """The lips' box grown by a quarter of its larger side (occl54's ``box``)."""
    lo, hi = lips.min(0), lips.max(0)
    pad = 0.25 * (hi - lo).max()
    return (*(lo - pad).astype(int), *(hi + pad).astype(int))


@pytest.fixture(scope="module")
def boxed(data_dir, arkit_model_path, tmp_path_factory):
    """``boxed.mp4`` (driving_d6's first frames, the box over the mouth in :data:`COVERED`), its
    track by ``track --occluders`` and the same track untested; a source clip of driving_d9's
    first frames and its track; the lips' own box (x0, y0, x1, y1) in each frame."""
    d = tmp_path_factory.mktemp("occltransfer")
    video = data_dir / "video"
    frames, fps = read_video(video / "driving_d6.mp4", max_frames=N_FRAMES)[:2]
    lips = np.load(video / "driving_d6.mediapipe478.npz")["landmarks"][:N_FRAMES, LIPS, :2]
    for i in COVERED:
        x0, y0, x1, y1 = _box(lips[i])
        cv2.rectangle(frames[i], (x0, y0), (x1, y1), HAND, -1)
    write_video(d / "boxed.mp4", frames, fps)
    source, sfps = read_video(video / "driving_d9.mp4", max_frames=N_FRAMES)[:2]
    write_video(d / "source.mp4", source, sfps)
    for name, more in (("boxed", ("--occluders",)), ("source", ())):
        assert _cli("track", d / f"{name}.mp4", "--model", arkit_model_path, "--out",
                    d / f"{name}.npz", "--no-progress", *more) == 0
    tested = Track.load(d / "boxed.npz")
    assert tested.occluded is not None and tested.occluded[list(COVERED), 0].sum() >= 6
    # flagged a frame or two around the box as ``track --occluders`` does (occl54: 28-61 of
    # 30-59), nowhere else
    assert not tested.occluded[:COVERED.start - 2].any()
    assert not tested.occluded[COVERED.stop + 2:].any()
    dataclasses.replace(tested, occluded=None).save(d / "untested.npz")
    return d, [(*lips[i].min(0).astype(int), *lips[i].max(0).astype(int))
               for i in range(N_FRAMES)]


def _pairs(d: Path) -> Path:
    """A pairs manifest: the boxed clip with its tested track (``kept``) and untested
    (``over``), driving_d9's expressions."""
    man = d / "pairs.csv"
    with open(man, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "target", "target_track", "expression_from", "source_track"])
        for name, track in (("kept", "boxed.npz"), ("over", "untested.npz")):
            w.writerow([name, "boxed.mp4", track, "source.mp4", "source.npz"])
    return man


def _mattes(folder: Path) -> np.ndarray:
    return np.stack([cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in sorted(folder.iterdir())])


def test_batch_transfer_keeps_an_occluder_as_transfer_does(boxed, arkit_model_path,
                                                           monkeypatch, tmp_path, capsys):
    """The batch's row of the tested track is ``transfer --target-track`` of it, result and
    matte to the bit; over the lips the matte is (nearly) 0 in each frame the test found
    covered (the target's pixels: the hand in front), where the row of the untested track
    paints the new face over them, wholly (1)."""
    d, boxes = boxed
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")    # each renders its own frames
    monkeypatch.setattr(batch_cluster, "open_client",
                        functools.partial(batch_cluster.open_client, processes=False))
    common = ("--model", arkit_model_path, "--crf", "0", "--no-progress")
    single = tmp_path / "single"
    (single / "m").mkdir(parents=True)
    assert _cli("transfer", "--target", d / "boxed.mp4", "--target-track", d / "boxed.npz",
                "--expression-from", d / "source.mp4", "--source-track", d / "source.npz",
                "--out", single / "kept.mp4", "--matte", single / "m" / "%05d.png", *common) == 0
    out = tmp_path / "out"
    assert _cli("batch", "transfer", "--manifest", _pairs(d), "--out", out, "--workers", "1",
                "--matte", "png", *common) == 0, capsys.readouterr()
    got, want = read_video(out / "kept.mp4")[0], read_video(single / "kept.mp4")[0]
    assert len(got) == len(want) == N_FRAMES
    assert all(np.array_equal(a, b) for a, b in zip(got, want))
    kept, over = _mattes(out / "kept.matte"), _mattes(out / "over.matte")
    assert np.array_equal(kept, _mattes(single / "m"))
    found = np.flatnonzero(Track.load(d / "boxed.npz").occluded[:, 0])
    for i in range(N_FRAMES):
        x0, y0, x1, y1 = boxes[i]                           # the lips' own box, within the hand
        if i in found:
            assert kept[i, y0:y1, x0:x1].max() < 0.01 * 65535, i   # the target's: the hand
        assert over[i, y0:y1, x0:x1].min() == 65535, i      # untested: the new face over it
    assert np.array_equal(kept[0], over[0])                  # where nothing is covered
