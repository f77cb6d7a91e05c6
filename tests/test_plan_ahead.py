"""What a transfer makes of its render's set-up on a thread while the target is tracked
(:func:`facetransfer.transfer_plan._setup_ahead`): the regions' model parts and OpenCV's
CIELAB tables, as the regions and the render would make them."""

import numpy as np
import pytest

from facetransfer import transfer_plan as tp
from facetransfer.rewrite_options import RewriteOptions


def test_the_model_parts_made_ahead_are_the_regions_own(arkit_model):
    """What :func:`facetransfer.transfer_plan._model_parts` makes is what
    :func:`facetransfer.region_views.region_textures` would make itself; none of the rig
    where no region is made."""
    from facetransfer.arkit import expression_rig
    from facetransfer.topology import mesh_topology

    topo, rig = tp._model_parts(arkit_model, RewriteOptions())
    own, own_rig = mesh_topology(arkit_model), expression_rig(arkit_model,
                                                               arkit_model.default_weights())
    for f in ("faces", "mouth_faces", "mouth_loop"):
        if hasattr(own, f):
            assert np.array_equal(getattr(topo, f), getattr(own, f)), f
    assert all(np.array_equal(np.asarray(a), np.asarray(b))
               for a, b in zip(vars(rig).values(), vars(own_rig).values()))
    assert tp._model_parts(arkit_model, RewriteOptions(eyes="target", jaw="frame"))[1] is None
    assert tp._made_ahead(None) == (None, None)


@pytest.mark.parametrize("options, made", [
    (RewriteOptions(), 1),
    (RewriteOptions(lip_colour="source"), 0),
    (RewriteOptions(mouth="function"), 0),
])
def test_the_lab_tables_are_made_ahead_where_the_render_converts(arkit_model, monkeypatch,
                                                                 options, made):
    """The lip colour's first CIELAB conversion (OpenCV's tables) is made ahead where the
    render reads the target's lip colour against another clip's mouth frame, else not."""
    import facetransfer.lip_colour as lc

    if arkit_model.landmarks is None:
        pytest.skip("a model without landmarks reads no lip colour")
    calls = []
    monkeypatch.setattr(lc, "rgb_to_lab", lambda rgb: calls.append(np.shape(rgb)))
    tp._lab_tables(arkit_model, options)
    assert calls == [(1, 3)] * made


@pytest.mark.parametrize("second_interrupt", [False, True])
def test_an_error_in_the_targets_track_leaves_no_set_up_thread_behind(monkeypatch,
                                                                       second_interrupt):
    """The target's track fails while the set-up thread still works: the child is cancelled
    and the error raised once that thread has ended (nothing goes on behind the caller), also
    where a second Ctrl-C cuts the child's grace short (that thread, left running as the
    interpreter exited, aborted the process)."""
    import time

    from facetransfer.errors import VideoError
    from facetransfer.track import obtain

    frames = np.zeros((3, 8, 8, 3), np.uint8)
    cancelled, made = [], []

    class Early:
        def cancel(self, grace):
            cancelled.append(grace)
            if second_interrupt:
                raise KeyboardInterrupt

    def slow_setup(model, options):
        time.sleep(0.3)
        return None, None

    def setup_ahead(model, options):
        from facetransfer.threads import Ahead

        made.append(Ahead(slow_setup, model, options))
        return made[-1]

    def no_face(self, *a, **k):
        raise VideoError("no face found in the target t.mp4")

    monkeypatch.setattr(tp._Planner, "read_target",
                        lambda self, sources, n, meanwhile=None: (frames, 25.0, (frames, 25.0)))
    monkeypatch.setattr(obtain, "start_background_track", lambda *a, **k: Early())
    monkeypatch.setattr(tp, "_setup_ahead", setup_ahead)
    monkeypatch.setattr(tp._Planner, "target_track", no_face)
    with pytest.raises(KeyboardInterrupt if second_interrupt else VideoError):
        tp.plan_sources(tp.TransferSources.of("t.mp4", expression_from="s.mp4"), object())
    assert len(cancelled) == 1 and made and made[0].done()


def test_the_forks_points_are_made_while_the_clips_decode(data_dir):
    """``read_target``'s ``meanwhile`` runs while both clips decode (the reader here waits for
    it: called after the decoding, the read would time out)."""
    import threading

    from facetransfer.errors import VideoError

    clips = data_dir / "video"
    called = threading.Event()

    def reader(path, max_frames=None):
        if not called.wait(10):
            raise VideoError(f"{path}: read before meanwhile was called")
        return np.zeros((4, 8, 8, 3), np.uint8), 25.0

    planner = tp._Planner(object(), "auto", None, None, {"read": 0.0, "track": 0.0}, reader)
    sources = tp.TransferSources.of(clips / "driving_d9.mp4",
                                    expression_from=clips / "driving_d6.mp4")
    frames, fps, pre_read = planner.read_target(sources, 4, called.set)
    assert called.is_set() and len(frames) == 4 and pre_read is not None


def test_the_forks_points_are_made_where_a_source_is_to_be_tracked(monkeypatch):
    import facetransfer.track.capture as capture

    made = []
    monkeypatch.setattr(capture, "prepare_points", lambda model: made.append(model))
    of = tp.TransferSources.of
    assert tp._before_fork(of("t.mp4"), "m", RewriteOptions(), None) is None
    assert tp._before_fork(of("t.mp4", expression_from="s.mp4", expression_track="s.npz"), "m",
                           RewriteOptions(), None) is None
    assert tp._before_fork(of("t.mp4", expression_from="s.mp4"), "m", RewriteOptions(),
                           False) is None
    tp._before_fork(of("t.mp4", expression_from="s.mp4"), "m", RewriteOptions(), None)()
    tp._before_fork(of("t.mp4", expression_from="s.mp4"), "m",
                    RewriteOptions(track_method="flow"), None)()
    assert made == ["m"]
