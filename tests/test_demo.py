"""The demo end to end on a few frames of the real clips (quick model to keep it short)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.demo import run_demo, side_by_side


def test_side_by_side_layout():
    src = np.full((48, 64, 3), 10, np.uint8)
    tgt = np.full((40, 40, 3), 20, np.uint8)
    res = np.full((40, 40, 3), 30, np.uint8)
    f = side_by_side(src, tgt, res, labels=False)
    assert f.shape == (40, 120, 3)
    np.testing.assert_array_equal(f[:, 40:80], tgt)
    np.testing.assert_array_equal(f[:, 80:], res)


@pytest.mark.slow
def test_demo_end_to_end(data_dir, quick_model, tmp_path):
    from facetransfer.io.video import read_video
    from facetransfer.rewrite import has_audio
    from facetransfer.track import Track

    res = run_demo(tmp_path / "out", frames=6, model=quick_model)
    assert res.video.is_file() and res.sheet.is_file() and res.track.is_file()
    frames, fps = read_video(res.video)
    assert frames.shape == (6, 512, 3 * 512, 3) and fps == 25.0
    assert has_audio(res.video)  # the target's audio is kept
    tr = Track.load(res.track)
    assert tr.n_frames == 6 and not tr.lost.all()
    # the result differs from the target only around the face: the top rows are the target's
    tgt, res_ = frames[3, :, 512:1024].astype(int), frames[3, :, 1024:].astype(int)
    assert np.abs(tgt[40:60] - res_[40:60]).mean() < 3
    assert np.abs(tgt[250:350, 180:330] - res_[250:350, 180:330]).mean() > 1
    with pytest.raises(ValueError, match="exists"):
        run_demo(tmp_path / "out", frames=6, model=quick_model, overwrite=False)
