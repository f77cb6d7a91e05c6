"""The track cache's key and the readers (helper review52c): a clip read otherwise is tracked
again whatever read it otherwise, and a docstring is not code (BENCHMARKS.md, "Fifty-second
session (helper review52c)")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from facetransfer.io import video_read
from facetransfer.io.video import encode_video
from facetransfer import code_digest
from facetransfer.track import cache


class _Model:
    content_hash = "m"


def test_a_clip_read_otherwise_has_another_key(tmp_path, monkeypatch):
    """The same file read as mirrored, or on another timeline, or as fewer frames (a trimmed
    clip's hidden frames, which the ffmpeg binary's listing decides: no digest of the code
    sees it) is another key; read the same, the same key. Before, the key named the file and
    the code only: a track of the clip read the old way was taken."""
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    clip = encode_video(tmp_path / "c.mp4", np.full((12, 32, 32, 3), 90, np.uint8), 25).path
    key = cache.track_key(clip, 12, "capture", None, _Model())
    assert key == cache.track_key(clip, 12, "capture", None, _Model())
    read = video_read.video_info(clip)
    for other in (replace(read, mirrored=True), replace(read, steps=tuple(range(12))),
                  replace(read, n_frames=11), replace(read, turn=90)):
        monkeypatch.setattr(video_read, "video_info", lambda path, other=other: other)
        assert cache.track_key(clip, 12, "capture", None, _Model()) != key


def test_a_docstring_or_a_comment_is_not_code(tmp_path):
    """Rewording a reader's docstring or comment keeps every cached track (before: the file's
    bytes were digested, so every user's tracks were made again); a change of its code does
    not."""
    src = tmp_path / "io" / "video_read.py"
    src.parent.mkdir()

    def digest(text):
        src.write_text(text)
        return code_digest.code_digest(tmp_path, [src], "v", code_only=True)

    code = '"""A reader."""\n\ndef f(x):\n    """One."""\n    return x + 1  # add\n'
    same = '"""The reader, reworded."""\n\n\ndef f(x):\n    """Two."""\n    return x + 1\n'
    other = '"""A reader."""\n\ndef f(x):\n    """One."""\n    return x + 2  # add\n'
    assert digest(code) == digest(same) != digest(other)
    assert code_digest.code_digest(tmp_path, [src], "v") != digest(same)   # the render cache's: bytes



def test_a_files_code_is_parsed_once_a_version(tmp_path, monkeypatch):
    """The fingerprint's files are parsed once a version (the memo in the user cache, keyed by
    their bytes: every command that tracked spent 0.46 CPU-s parsing them, 0.35 more than the
    bytes' digest); the same digest from the memo, another once the file changes, and a memo
    that is not JSON is taken for none."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    src = tmp_path / "io" / "video_read.py"
    src.parent.mkdir()
    src.write_text('"""A reader."""\n\ndef f(x):\n    return x + 1\n')
    first = code_digest.code_digest(tmp_path, [src], "v", code_only=True)
    parse = code_digest._code_of
    monkeypatch.setattr(code_digest, "_code_of", lambda data: (_ for _ in ()).throw(
        AssertionError("parsed again")))
    assert code_digest.code_digest(tmp_path, [src], "v", code_only=True) == first
    monkeypatch.setattr(code_digest, "_code_of", parse)
    src.write_text('"""A reader."""\n\ndef f(x):\n    return x + 2\n')
    assert code_digest.code_digest(tmp_path, [src], "v", code_only=True) != first
    (tmp_path / "cache" / "facetransfer" / code_digest.CODE_MEMO).write_text("{not json")
    src.write_text('"""A reader."""\n\ndef f(x):\n    return x + 1\n')
    assert code_digest.code_digest(tmp_path, [src], "v", code_only=True) == first
