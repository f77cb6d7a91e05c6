"""What a compositor's walk found (forty-third session): a plate rewritten into a sequence,
its outputs, its hand-off to animation."""

from __future__ import annotations

import pytest


def test_an_output_sequence_under_a_file_is_refused_by_name(tmp_path):
    """``--out afile/x.%04d.png`` with ``afile`` a file: refused before any work, saying so
    (was: checked, then ``File exists: afile`` after the tracking)."""
    from facetransfer.io.video import VideoError, check_video_output

    (tmp_path / "afile").write_text("x")
    for out in (tmp_path / "afile" / "x.%04d.png", tmp_path / "afile" / "sub" / "x.%04d.exr"):
        with pytest.raises(VideoError, match=f"output folder {tmp_path / 'afile'} is a file, "
                                             "not a folder"):
            check_video_output(out)
    assert check_video_output(tmp_path / "new" / "x.%04d.png").kind == "images"


def test_a_deep_video_with_alpha_written_as_tiff_is_said_why_it_is_8_bits(tmp_path, caplog):
    """A ProRes 4444 target (10 bits, alpha) written as a TIFF sequence is written in 8 bits
    (with its alpha: OpenCV writes no 16-bit TIFF alpha); the warning said a TIFF sequence
    would keep the bits, the very output asked for. Now it names the ones that do."""
    import logging
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).parent))
    from test_plate_alpha import _prores_4444

    from facetransfer.io.video_like import like_video

    rgba = np.full((2, 32, 32, 4), 200, np.uint8)
    mov = _prores_4444(tmp_path / "a.mov", rgba)
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        like_video(None, mov, tmp_path / "o" / "x.%04d.tif")
    said = [r.getMessage() for r in caplog.records if "bits a sample" in r.getMessage()]
    assert len(said) == 1 and "a TIFF sequence with alpha is written in 8 bits" in said[0]
    assert "PNG or DPX sequence, keeps them" in said[0]
