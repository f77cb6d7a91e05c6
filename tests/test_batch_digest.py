"""The job digests of batch runs (:mod:`facetransfer.batch.digest`) and the content digests they
hold (:func:`facetransfer.io.verified.content_digest`): of what makes an output, not of where its
files lie; the format before still read."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from facetransfer.batch import digest
from facetransfer.batch.manifest import ClipJob, ExportJob, PairJob
from facetransfer.io import verified


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A user cache of the test's own; the number of files hashed, counted."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    read = []
    real = verified._sha256
    monkeypatch.setattr(verified, "_sha256", lambda p: (read.append(Path(p).name), real(p))[1])
    return read


def _old(path: Path, seconds: float = 60.0) -> Path:
    """``path`` dated ``seconds`` ago (a file written just now is not remembered: racy)."""
    t = path.stat().st_mtime - seconds
    os.utime(path, (t, t))
    return path


def _project(root: Path, video: bytes = b"frames of a", points: bytes = b"[[1, 2]]") -> Path:
    (root / "clips").mkdir(parents=True)
    (root / "clips" / "a.mp4").write_bytes(video)
    (root / "clips" / "a.json").write_bytes(points)
    for f in (root / "clips").iterdir():
        _old(f)
    return root


def _clip(root: Path, **kw) -> ClipJob:
    return ClipJob("a", str(root / "clips" / "a.mp4"), str(root / "clips" / "a.json"), **kw)


def test_a_jobs_key_is_of_its_inputs_content_not_their_place(tmp_path, cache):
    """The same clip, points and options in a moved and in a copied folder: one key (the
    format before had one per place: the paths and inodes were in it); another byte in the
    clip, other points, another face, frame limit, name or options: another key."""
    a = _project(tmp_path / "a")
    key = digest.job_key(_clip(a), "track opts model")
    assert key.startswith(digest.KEY_FORMAT) and len(key) == len(digest.KEY_FORMAT) + 16
    b = tmp_path / "disk2" / "b"
    shutil.copytree(a, b)
    moved = tmp_path / "moved"
    os.rename(a, moved)
    assert digest.job_key(_clip(b), "track opts model") == key
    assert digest.job_key(_clip(moved), "track opts model") == key
    assert digest.legacy_job_key(_clip(b), "w") != digest.legacy_job_key(_clip(moved), "w")
    others = {digest.job_key(_clip(moved, face="left"), "track opts model"),
              digest.job_key(_clip(moved, max_frames=9), "track opts model"),
              digest.job_key(_clip(moved), "track other-opts model"),
              digest.job_key(ClipJob("b", str(moved / "clips" / "a.mp4"),
                                     str(moved / "clips" / "a.json")), "track opts model"),
              digest.job_key(ClipJob("a", str(moved / "clips" / "a.mp4")), "track opts model")}
    (b / "clips" / "a.json").write_bytes(b"[[1, 3]]")
    others.add(digest.job_key(_clip(b), "track opts model"))
    (b / "clips" / "a.json").write_bytes(b"[[1, 2]]")
    (b / "clips" / "a.mp4").write_bytes(b"frames of A")       # same name and size
    others.add(digest.job_key(_clip(b), "track opts model"))
    (b / "clips" / "a.mp4").unlink()
    others.add(digest.job_key(_clip(b), "track opts model"))  # missing: its task says so
    assert key not in others and len(others) == 8


def test_a_pairs_key_does_not_hang_on_its_manifests_column_order(tmp_path, cache):
    for n in ("t.mp4", "s.mp4"):
        (tmp_path / n).write_bytes(n.encode())
    t, s = str(tmp_path / "t.mp4"), str(tmp_path / "s.mp4")
    one = PairJob("p", Path(t), {"expression_from": s, "identity_label": "3"})
    two = PairJob("p", Path(t), {"identity_label": "3", "expression_from": s})
    assert digest.job_key(one, "w") == digest.job_key(two, "w")
    assert digest.job_key(PairJob("p", Path(t), {"expression_from": s, "identity_label": "4"}),
                          "w") != digest.job_key(one, "w")
    swapped = PairJob("p", Path(s), {"expression_from": t, "identity_label": "3"})
    assert digest.job_key(swapped, "w") != digest.job_key(one, "w")


def test_an_image_sequences_key_is_of_its_frames(tmp_path, cache, monkeypatch):
    """A plate of numbered frames: the same frames moved keep its key; a frame changed,
    added or renumbered, or another rate said, change it."""
    from facetransfer.io.atomic import write_image

    plate = tmp_path / "plate"
    plate.mkdir()
    for k in range(1001, 1004):
        write_image(plate / f"kh.{k}.png", np.full((4, 6, 3), k % 256, np.uint8))
    job = ClipJob("kh", str(plate / "kh.####.png"))
    key = digest.job_key(job, "w")
    assert digest.input_digest(plate / "kh.####.png").startswith("sequence:3:")
    os.rename(plate, tmp_path / "p2")
    assert digest.job_key(ClipJob("kh", str(tmp_path / "p2" / "kh.####.png")), "w") == key
    os.rename(tmp_path / "p2", plate)
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    assert digest.job_key(job, "w") != key
    monkeypatch.delenv("FACETRANSFER_SEQUENCE_FPS")
    assert digest.job_key(job, "w") == key
    write_image(plate / "kh.1004.png", np.zeros((4, 6, 3), np.uint8))
    assert digest.job_key(job, "w") != key
    (plate / "kh.1004.png").unlink()
    assert digest.job_key(job, "w") == key
    os.rename(plate / "kh.1003.png", plate / "kh.1005.png")   # renumbered (the docstring's)
    assert digest.job_key(job, "w") != key
    os.rename(plate / "kh.1005.png", plate / "kh.1003.png")
    write_image(plate / "kh.1002.png", np.zeros((4, 6, 3), np.uint8), overwrite=True)
    assert digest.job_key(job, "w") != key


def test_a_files_content_is_read_once_and_remembered_by_its_identity(tmp_path, cache):
    """A rerun does not read its inputs again (gigabytes of video): the digest is remembered
    by the file's device, inode, size and time, also when its folder is renamed on its disk;
    a copy is read once, an edit is read again; a file written in the last RACY_SECONDS is
    not remembered (its time could hide a rewrite)."""
    import hashlib

    f = tmp_path / "d" / "clip.mp4"
    f.parent.mkdir()
    f.write_bytes(b"x" * 3000)
    _old(f)
    with verified.remembered_digests() as memo:
        first = verified.content_digest(f, memo)
    assert first == f"3000:{hashlib.sha256(b'x' * 3000).hexdigest()}"
    assert cache == ["clip.mp4"]
    os.rename(tmp_path / "d", tmp_path / "e")
    moved = tmp_path / "e" / "clip.mp4"
    with verified.remembered_digests() as memo:
        assert verified.content_digest(moved, memo) == first
    assert cache == ["clip.mp4"]
    copy = tmp_path / "copy.mp4"
    shutil.copy2(moved, copy)
    for _ in range(2):
        with verified.remembered_digests() as memo:
            assert verified.content_digest(copy, memo) == first
    assert cache == ["clip.mp4", "copy.mp4"]
    copy.write_bytes(b"y" * 3000)                 # now: hashed, not remembered
    for _ in range(2):
        with verified.remembered_digests() as memo:
            assert verified.content_digest(copy, memo) != first
    assert cache == ["clip.mp4", "copy.mp4", "copy.mp4", "copy.mp4"]
    record = tmp_path / "cache" / "facetransfer" / verified.DIGESTS
    assert len(record.read_text().splitlines()) == 4       # braces and the two files


def test_the_key_of_the_format_before_is_the_one_it_wrote(tmp_path):
    """:func:`legacy_job_key` is the digest facetransfer wrote before the ``v2:`` format
    (values computed by that version's ``batch.run.job_key``); only a key of its form is
    compared with it."""
    assert digest.legacy_job_key(ExportJob("t", Path("/nonexistent/t.npz")),
                                 "export json None None default") == "c1a2914ef075a7ca"
    assert digest.legacy_job_key(ClipJob("a", "/nonexistent/a.mp4", "/nonexistent/a.json",
                                         "left", 20),
                                 "track TrackerSettings() chunk=0 abc") == "b6f516df6e597c88"
    asked = []

    def legacy():
        asked.append(1)
        return "c1a2914ef075a7ca"

    assert digest.same_job("v2:00", "v2:00", legacy) and not asked
    assert not digest.same_job("v2:01", "v2:00", legacy) and not asked
    assert not digest.same_job("unknown", "v2:00", legacy) and not asked
    assert digest.same_job("c1a2914ef075a7ca", "v2:00", legacy) and asked == [1]
    assert not digest.same_job("c1a2914ef075a7cb", "v2:00", legacy)


def test_a_key_of_options_worded_as_before_is_asked_only_for_this_format():
    """``before()`` (this job's key with its options as a version before wrote them) is
    compared with a ``v2:`` key that differs from this run's only, never with a key of the
    format before (``legacy``'s) nor with one of no format."""
    asked = []

    def before():
        asked.append(1)
        return "v2:01"

    assert digest.same_job("v2:00", "v2:00", None, before) and not asked
    assert not digest.same_job("c1a2914ef075a7ca", "v2:00", None, before) and not asked
    assert not digest.same_job("unknown", "v2:00", None, before) and not asked
    assert digest.same_job("v2:01", "v2:00", None, before) and asked == [1]
    assert not digest.same_job("v2:02", "v2:00", None, before) and asked == [1, 1]


def test_a_batch_transfers_options_leave_their_defaults_out():
    """``batch transfer``'s options in its digests: an option added at its default (a setting
    of None, as ``--align`` unset) leaves them as they were, so that a version adding one keeps
    every earlier output (before: every setting's ``repr``, which any added key changed); an
    option changed, the video's included, changes them."""
    import types

    from facetransfer.batch.run import _transfer_what_before, transfer_what
    from facetransfer.io.video_options import VideoOptions

    model = types.SimpleNamespace(content_hash="abc")
    settings = {"texture": "frame", "blend": "fast", "mouth": None, "align": None,
                "max_frames": None, "track_method": "auto", "speed": "fast", "eyes": "model",
                "jaw": "closed", "lips": "residual", "lip_colour": "target",
                "gaze": "performance", "video": VideoOptions()}
    what = transfer_what(settings, model)
    assert what == "transfer RewriteOptions() video=VideoOptions() abc"
    assert transfer_what({**settings, "new_option": None}, model) == what
    assert _transfer_what_before({**settings, "new_option": None}, model) != \
        _transfer_what_before(settings, model)
    changed = {transfer_what({**settings, **more}, model) for more in (
        {"blend": "poisson"}, {"max_frames": 30}, {"align": "loop"},
        {"video": VideoOptions(crf=0)}, {"video": None})}
    assert len(changed) == 5 and what not in changed
    assert transfer_what(settings, types.SimpleNamespace(content_hash="abd")) != what


def test_a_takes_labels_are_always_named_in_its_digest(monkeypatch):
    """``batch export``'s options in its digests: a livelink take's labels named whether said
    or the default (before: the default left out, so a take of the old default, the clip's
    frames, had the digest of the new one's); a later default is another digest; the other
    formats' words are those they had (the legacy key's test above)."""
    from facetransfer.batch.run import _export_what
    from facetransfer.export import livelink

    assert _export_what("livelink", "None", None, None) == \
        "export livelink None None default labels app angles app"
    assert _export_what("livelink", "None", 3, None, "clip") == \
        "export livelink None 3 default labels clip angles app"
    assert _export_what("json", "None", None, None) == "export json None None default"
    monkeypatch.setattr(livelink, "DEFAULT_LABELS", "clip")
    assert _export_what("livelink", "None", None, None).endswith(" labels clip angles app")


def test_an_option_that_is_a_file_is_its_content(tmp_path, cache):
    tex = tmp_path / "tex.png"
    tex.write_bytes(b"texture")
    text = digest.value_text(tex)
    assert text == digest.value_text(str(tex)) and "7:" in text and str(tmp_path) not in text
    a = np.arange(6, dtype=np.uint8).reshape(2, 3)
    assert digest.value_text(a) == digest.value_text(a.copy()) != digest.value_text(a + 1)
    assert digest.value_text(None) == "None" and digest.value_text(3) == "3"


def test_a_clips_precomputed_points_are_part_of_its_key(tmp_path, cache):
    """``NAME.mediapipe478.npz`` beside a clip (what ``--tracker landmarks`` fits to): added,
    changed or removed, another key (before, a rerun kept the track fitted to the old points)."""
    a = _project(tmp_path / "a")
    key = digest.job_key(_clip(a), "track landmarks model")
    side = a / "clips" / "a.mediapipe478.npz"
    side.write_bytes(b"points one")
    _old(side)
    with_side = digest.job_key(_clip(a), "track landmarks model")
    side.write_bytes(b"points two")
    _old(side, 30.0)
    changed = digest.job_key(_clip(a), "track landmarks model")
    side.unlink()
    assert len({key, with_side, changed}) == 3
    assert digest.job_key(_clip(a), "track landmarks model") == key
