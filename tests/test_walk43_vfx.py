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
