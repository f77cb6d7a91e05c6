"""reread56: three of the fifty-sixth session's promises that its own tests left untested.

- ``mouth_texture_function(tex_size="auto", on_frames=...)`` announces the frames it lifts
  *after* the memory bound trimmed them (review56b's bar: a 4K mouth's 83 of 120); its test
  drew every frame of a 64² face, where nothing is trimmed.
- ``transfer --performance P --save-track NEW``: the new performance is marked ``made_by``
  even where ``P`` is not (a clip's own track given as the performance); savetrack56's tests
  only saved a recombined transfer's, or rendered a file already marked.
- each of the five clip track options refuses a marked file (the CLI tests give four).
"""

from __future__ import annotations

import sys

import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.track import Track  # noqa: E402
import test_transfer_cli  # noqa: E402

clips = test_transfer_cli.clips          # its fixture: the synthetic target and source clips


def test_on_frames_counts_the_frames_the_memory_bound_keeps(quick_model, monkeypatch):
    """With the bound keeping 2 of the face's 3 frames (:func:`mouth_tex_size` asked), the
    count announced, the bar's steps and the frames in the function are all 2."""
    import facetransfer.texture.face as ftex
    from test_mouth_res56 import _scene

    frames, track, topo, _ = _scene(quick_model, 64, 4.0)
    assert len(frames) > 2
    monkeypatch.setattr(ftex, "mouth_tex_size", lambda texels, n, **kw: (64, 2))
    seen = []
    fn = ftex.mouth_texture_function(quick_model, frames, track, topo, tex_size="auto",
                                     on_frames=lambda n: seen.append(("total", n)),
                                     progress=lambda n: seen.append(("step", n)))
    assert fn.frames.size == 2
    assert seen == [("total", 2)] + [("step", 1)] * 2


def test_a_performance_without_the_mark_is_saved_with_it(clips, quick_model_path, tmp_path):
    """The target's own track (no mark) rendered as ``--performance``: what ``--save-track``
    writes is the new performance, marked ``transfer``, and the file given is left as it was."""
    saved = tmp_path / "new.npz"
    code = main([str(a) for a in (
        "transfer", "--target", clips["target"], "--target-track", clips["target_track"],
        "--performance", clips["target_track"], "--model", quick_model_path,
        "--save-track", saved, "--out", tmp_path / "out.mp4", "--no-progress")])
    assert code == 0
    assert Track.load(saved).made_by == "transfer"
    assert Track.load(clips["target_track"]).made_by == ""
    with np.load(clips["target_track"]) as z:
        assert "made_by" not in z.files


def test_every_clip_track_option_refuses_a_marked_file(quick_track, tmp_path):
    """``check_given_tracks`` for each of the five clip track options (savetrack56's CLI tests
    cover four, not ``--viseme-track``), and a mark other than a transfer's is named as such."""
    import dataclasses
    import re

    import pytest

    from facetransfer.errors import RewriteError
    from facetransfer.transfer_plan import TransferSources, check_given_tracks

    for made, words in (("transfer", "a transfer's saved performance"),
                        ("an edit", "a performance made by an edit")):
        perf = tmp_path / f"{made[:2]}.npz"
        dataclasses.replace(quick_track, made_by=made).save(perf)
        for kind, flag in (("target", "--target-track"), ("expression", "--source-track"),
                           ("viseme", "--viseme-track"), ("identity", "--identity-track"),
                           ("pose", "--pose-track")):
            kw = ({"target_track": perf} if kind == "target"
                  else {f"{kind}_from": "s.mp4", f"{kind}_track": perf})
            with pytest.raises(RewriteError, match="^" + re.escape(f"{flag} {perf} is {words}")):
                check_given_tracks(TransferSources.of("t.mp4", **kw))
        check_given_tracks(TransferSources.of("t.mp4", target_track=tmp_path / "none.npz"))
