"""Tests of the speed options of the transfer: tracking presets, the face-box crop of the
rewrite and the background (forked) tracking of the expression source."""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer import frame_meshes
from facetransfer import lip_colour  # noqa: E402
from facetransfer import rewrite as rw  # noqa: E402
from facetransfer import rewrite_clip as rc  # noqa: E402
from facetransfer.texture import face as ftex  # noqa: E402
from facetransfer.track import obtain  # noqa: E402
from facetransfer.track import presets  # noqa: E402
from facetransfer import rewrite_options as rwo  # noqa: E402
from facetransfer import topology  # noqa: E402
from facetransfer import transfer_plan as tp  # noqa: E402
from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.tracker import TrackOptions  # noqa: E402
from facetransfer.transfer import recombine  # noqa: E402
from test_transfer_cli import clips, run  # noqa: E402,F401 (fixture)
from test_transfer_rewrite import face_texture, synthetic, topo  # noqa: E402,F401 (fixtures)


def test_track_options_presets():
    assert presets.track_options("balanced") == TrackOptions(reselect=4)
    fast = presets.track_options("fast")
    assert (fast.passes, fast.levels, fast.n_points, fast.snap_frames, fast.reselect,
            fast.half_window) == (1, 2, 500, 4, 8, 3)
    assert presets.track_options("quality").passes == 3
    assert presets.track_options("quality").reselect == 1
    assert presets.track_options() == fast and presets.DEFAULT_SPEED == "fast"
    with pytest.raises(rwo.RewriteError, match="speed must be one of fast, balanced, quality"):
        presets.track_options("turbo")


def test_plan_rejects_unknown_speed_before_any_work(quick_model, tmp_path):
    # the target does not exist: the preset is checked first
    with pytest.raises(rwo.RewriteError, match="speed"):
        tp.plan_transfer(tmp_path / "missing.mp4", quick_model, speed="ludicrous")


@pytest.mark.parametrize("blend", ["fast", "poisson", "none"])
def test_face_box_crop_matches_the_full_frame(quick_model, topo, synthetic, blend):
    """The rewrite of the face's bounding box, pasted back, equals the full-frame rewrite."""
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    for i in (1, 3):
        V = topology.close_mouth(quick_model.synthesize(new.weights_at(i)), topo)
        Vt = topology.close_mouth(quick_model.synthesize(tb.weights_at(i)), topo)
        Vs = topology.close_mouth(quick_model.synthesize(ta.weights_at(i)), topo)
        tex = ftex.FaceTexture(fb[i], ftex.frame_uvs(Vt, tb.camera(i), (128, 128)), i)
        mouth = ftex.FaceTexture(fa[i], ftex.frame_uvs(Vs, ta.camera(i), (128, 128)), i)
        blending = rwo.BlendOptions(blend)
        cropped = rw.rewrite_frame(fb[i], V, new.camera(i), topo,
                                   rw.FrameTextures(tex, mouth), blending=blending)
        full = rw._rewrite_crop(fb[i], V, new.camera(i), topo, rw.FrameTextures(
            tex, mouth, mouth_ring=rw.mouth_ring_faces(topo)), blending)
        box = rw._face_box(V, new.camera(i), (128, 128), margin=20)
        assert box is not None and box != (0, 0, 128, 128)  # the crop really is smaller
        for a, b in zip(dataclasses.astuple(cropped), dataclasses.astuple(full)):
            np.testing.assert_array_equal(a, b)
        assert cropped.face_mask.sum() > 2000


def test_face_box_off_screen_keeps_the_frame(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    cam = dataclasses.replace(tb.camera(0), translation=np.array([1000.0, 1000.0]))
    V = quick_model.synthesize(tb.weights_at(0))
    assert rw._face_box(topology.close_mouth(V, topo), cam, (128, 128), margin=4) is None
    Vt = topology.close_mouth(V, topo)
    tex = ftex.FaceTexture(fb[0], ftex.frame_uvs(Vt, tb.camera(0), (128, 128)), 0)
    out = rw.rewrite_frame(fb[0], V, cam, topo, rw.FrameTextures(tex))
    np.testing.assert_array_equal(out.image, fb[0])
    assert not out.face_mask.any()


def _fake_obtain_track(tracks):
    """obtain_track stand-in: the truth track of the video, its ``source`` = the process id."""

    def fake(video, model, **kw):
        name = Path(video).stem
        if name == "broken":
            raise VideoError(f"no face found in {video}")
        tr = Track.load(tracks[name])
        n = kw.get("max_frames")
        if n is not None and tr.n_frames > n:
            from facetransfer.track.project import take_frames

            tr = take_frames(tr, np.arange(n))
        return dataclasses.replace(tr, source=str(os.getpid()))

    return fake


def test_the_capture_points_kept_for_tracking_are_released_once_the_tracks_are_in(
        clips, quick_model, monkeypatch):
    """The capture's point sampler (24.5 MB for the default model, made for the target's fit
    and kept by track.capture_points for the next fit) was held by the transfer's parent
    through its whole render; a plan's tracks in, it is released (obtain.done_tracking)."""
    from facetransfer.track import capture_points

    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"]})

    def fitted(video, model, **kw):
        capture_points.sampler(model)                   # kept, as the capture's fit does
        return fake(video, model, **kw)

    monkeypatch.setattr(obtain, "obtain_track", fitted)
    monkeypatch.setattr(capture_points, "_SAMPLERS", {})
    tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                     parallel=False)
    assert capture_points._SAMPLERS == {}
    capture_points.sampler(quick_model)                 # a later fit makes it again
    assert len(capture_points._SAMPLERS) == 1


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_background_tracking_equals_sequential(clips, quick_model, monkeypatch, tmp_path):
    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"]})
    monkeypatch.setattr(obtain, "obtain_track", fake)
    plans = {par: tp.plan_transfer(clips["target"], quick_model,
                                   expression_from=clips["source"], parallel=par)
             for par in (False, True)}
    me = str(os.getpid())
    assert plans[False].source_tracks["expression"].source == me
    assert plans[True].source_tracks["expression"].source != me  # tracked in the child
    assert plans[True].source_tracks["target"].source == me
    for m in quick_model.mode_names:
        np.testing.assert_array_equal(plans[True].new_track.weights[m],
                                      plans[False].new_track.weights[m])
    np.testing.assert_array_equal(plans[True].mouth_index, plans[False].mouth_index)
    # an error of the tracking in the child reaches the caller
    import shutil

    broken = tmp_path / "broken.mp4"
    shutil.copy(clips["source"], broken)
    with pytest.raises(VideoError, match="no face found"):
        tp.plan_transfer(clips["target"], quick_model, expression_from=broken, parallel=True)


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_fast_detects_both_clips_every_other_frame_and_makes_the_regions_ahead(
        clips, quick_model, monkeypatch):
    """With ``speed="fast"`` the detector sees every other frame of the target and of the
    source (the source's also where the eyes move, :mod:`facetransfer.track.skip_rule`), in
    the forked child too; while the source is tracked in the background the
    target's region textures are made, for the render of this plan's target track."""
    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"]})
    calls, forked = [], []

    def recorded(video, model, **kw):
        calls.append((Path(video).stem, kw.get("detect_every", 1), kw.get("detect_eyes")))
        return fake(video, model, **kw)

    start = obtain.start_background_track

    def started(video, model, max_frames, **kw):
        forked.append((Path(video).stem, kw.get("detect_every", 1), kw.get("detect_eyes")))
        return start(video, model, max_frames, **kw)

    monkeypatch.setattr(obtain, "obtain_track", recorded)
    monkeypatch.setattr(obtain, "start_background_track", started)
    for speed, every in (("fast", 2), ("balanced", 1), ("quality", 1)):
        calls.clear(), forked.clear()
        plan = tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                                parallel=True, speed=speed)
        assert calls == [("target", every, False)]   # the source: in the forked child
        assert forked == [("source", every, True)]
        assert plan.regions is not None and plan.regions.target_track is plan.target_track
        assert plan.regions.n_frames == plan.n_frames and "regions" in plan.timings
    calls.clear()
    plan = tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                            parallel=False)
    assert calls == [("target", 2, False), ("source", 2, True)] and plan.regions is None


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_the_regions_made_on_their_thread_beside_the_source_basis_and_their_error(
        clips, quick_model, monkeypatch):
    """While the forked source is awaited the target's regions are made on a thread of their
    own and here the source's clip basis, for the render's meshes of it (the same identity
    rows the render's :class:`~facetransfer.frame_meshes.FrameMeshes` contracts); a first
    CIELAB conversion (OpenCV's tables, for the lip colour) is made on the set-up thread while
    the target is tracked; an error of the regions' thread reaches the caller."""
    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"]})
    monkeypatch.setattr(obtain, "obtain_track", fake)
    seen, threads = [], []
    basis = type(quick_model).clip_basis

    def recorded(model, weights):
        seen.append({m: np.array(w) for m, w in weights.items()})
        return basis(model, weights)

    made = tp._region_textures

    def on_thread(*args):
        import threading

        threads.append(threading.current_thread().name)
        return made(*args)

    lab = lip_colour.rgb_to_lab

    def converted(rgb):
        import threading

        threads.append(("lab", threading.current_thread().name))
        return lab(rgb)

    monkeypatch.setattr(type(quick_model), "clip_basis", recorded)
    monkeypatch.setattr(tp, "_region_textures", on_thread)
    monkeypatch.setattr(lip_colour, "rgb_to_lab", converted)
    plan = tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                            parallel=True)
    assert quick_model.landmarks is not None         # the lip colour's tables made here too
    assert sorted(threads, key=str) == [("lab", "setup-ahead"), "regions-ahead"]
    assert plan.regions.target_track is plan.target_track
    mouth = plan.mouth_track.weights["identity"][:plan.n_frames]
    assert plan.mouth_frames is not plan.target_frames and len(seen) == 1
    np.testing.assert_array_equal(seen[0]["identity"], frame_meshes.constant_if_nearly(mouth))
    assert not np.array_equal(seen[0]["identity"][0], plan.target_track.weights["identity"][0])

    def broken(*args):
        raise RuntimeError("the regions failed")

    monkeypatch.setattr(tp, "_region_textures", broken)
    with pytest.raises(RuntimeError, match="the regions failed"):
        tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                         parallel=True)


def _regions_alive() -> bool:
    import threading

    return any(t.name == "regions-ahead" for t in threading.enumerate())


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_an_error_beside_the_regions_thread_is_raised_once_it_has_ended(
        clips, quick_model, monkeypatch, tmp_path):
    """An error of this thread while the regions' thread runs (the expression source without
    a face, an interrupt while recombining) is raised once that thread has ended: nothing of
    the plan goes on behind the caller (its log lines at the interpreter's exit, its process-
    wide one BLAS thread, its writes into the timings)."""
    import shutil
    import threading

    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"]})
    monkeypatch.setattr(obtain, "obtain_track", fake)
    ended = []

    def slow(*args):
        threading.Event().wait(2.0)         # still at work when this thread's error comes
        ended.append(threading.current_thread().name)

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(tp, "_region_textures", slow)
    broken = tmp_path / "broken.mp4"
    shutil.copy(clips["source"], broken)
    with pytest.raises(VideoError, match="no face found"):
        tp.plan_transfer(clips["target"], quick_model, expression_from=broken, parallel=True)
    assert ended == ["regions-ahead"] and not _regions_alive()
    monkeypatch.setattr(tp, "_recombined_plan", interrupted)
    with pytest.raises(KeyboardInterrupt):
        tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                         parallel=True)
    assert ended == ["regions-ahead"] * 2 and not _regions_alive()


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_a_source_tracked_here_waits_for_the_regions_thread(clips, quick_model, monkeypatch,
                                                            tmp_path):
    """A source tracked here after the forked one (a pose source; the forked track failed)
    is tracked with nothing beside it, as ``alone`` says (its detection in two processes,
    forked: not beside a thread at work), once the regions' thread has ended."""
    import shutil
    import threading

    fake = _fake_obtain_track({"target": clips["target_track"], "source": clips["source_track"],
                               "pose": clips["source_track"]})
    calls = []

    def recorded(video, model, **kw):
        calls.append((Path(video).stem, kw.get("workers"), _regions_alive()))
        return fake(video, model, **kw)

    made = tp._region_textures

    def slow(*args):
        threading.Event().wait(2.0)         # still at work when the pose source is tracked
        return made(*args)

    monkeypatch.setattr(obtain, "obtain_track", recorded)
    monkeypatch.setattr(tp, "_region_textures", slow)
    pose = tmp_path / "pose.mp4"
    shutil.copy(clips["source"], pose)
    plan = tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                            pose_from=pose, parallel=True)
    alone = tp.default_workers()
    assert calls == [("target", 1, False), ("pose", alone, False)]
    assert plan.regions is not None and "pose" in plan.source_tracks
    calls.clear()                       # the forked track failed: the source tracked here
    monkeypatch.setattr(obtain, "start_background_track", lambda *a, **k: _Failed())
    plan = tp.plan_transfer(clips["target"], quick_model, expression_from=clips["source"],
                            parallel=True)
    assert calls == [("target", 1, False), ("source", alone, False)]
    assert plan.regions is not None


class _Failed:
    """A background track that failed to run (its ``result`` None: tracked here instead)."""

    def result(self):
        return None

    def cancel(self, *, grace: float = 0.0):
        pass


def test_cli_speed_option(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "fast.mp4"
    code, stdout, err = run(["transfer", "--target", clips["target"], "--target-track",
                             clips["target_track"], "--expression-from", clips["source"],
                             "--source-track", clips["source_track"], "--model",
                             quick_model_path, "--out", out, "--speed", "fast",
                             "--no-progress"], capsys)
    assert code == 0, err
    assert out.is_file()
    with pytest.raises(SystemExit) as exc:
        run(["transfer", "--target", clips["target"], "--expression-from", clips["source"],
             "--model", quick_model_path, "--out", tmp_path / "x.mp4", "--speed", "turbo"],
            capsys)
    assert exc.value.code == 2
    assert "--speed" in capsys.readouterr().err
    assert not (tmp_path / "x.mp4").exists()


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs fork")
def test_rendering_in_processes_equals_one_thread(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    lost = new.lost.copy()
    lost[2] = True  # a lost frame keeps the original in both
    new = dataclasses.replace(new, lost=lost)
    runs = [list(rc.rewrite_frames(fb, tb, new, quick_model,
                                   mouth_source=rc.MouthSource(fa, ta), topo=topo,
                                   run=rc.RenderRun(workers=w, processes=p)))
            for w, p in ((1, False), (2, True))]
    for a, b in zip(*runs):
        for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b)):
            np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(runs[1][2].image, fb[2])
    assert runs[1][1].mouth_mask.any() and runs[1][1].face_mask.sum() > 2000


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_the_render_runs_blas_on_one_thread_and_restores_it(quick_model, topo, synthetic,
                                                            monkeypatch):
    """BLAS's threads would spin beside the render's own (BENCHMARKS.md, "Fortieth
    session"): one each while the frames are made (on one thread or two), as many as before
    once the generator is closed."""
    from threadpoolctl import threadpool_limits

    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    seen = []
    call = rc._ClipRenderer.__call__

    def spying_call(self, i):
        seen.append(_blas_threads())
        return call(self, i)

    monkeypatch.setattr(rc._ClipRenderer, "__call__", spying_call)
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        if not before or max(before) < 2:
            pytest.skip("no BLAS library with threads to limit")
        for workers in (1, 2):
            seen.clear()
            it = rc.rewrite_frames(fb, tb, new, quick_model,
                                   mouth_source=rc.MouthSource(fa, ta), topo=topo,
                                   run=rc.RenderRun(workers=workers))
            next(it)
            assert seen and all(s == [1] * len(before) for s in seen)
            assert _blas_threads() == [1] * len(before)  # while the render is suspended too
            it.close()
            assert _blas_threads() == before
        # two renders at once, the first made closed first: one thread until the last ends,
        # then as before (a limit per render restored the threads under the second and left
        # one thread after both)
        a, b = (rc.rewrite_frames(fb, tb, new, quick_model,
                                  mouth_source=rc.MouthSource(fa, ta), topo=topo,
                                  run=rc.RenderRun(workers=1)) for _ in range(2))
        next(a), next(b)
        a.close()
        assert _blas_threads() == [1] * len(before)
        next(b)
        assert seen[-1] == [1] * len(before)
        b.close()
        assert _blas_threads() == before


def test_crop_of_and_paste_round_trip(synthetic):
    fa, ta, fb, tb, truth = synthetic
    T = fb[0]
    img = T.copy()
    img[30:40, 50:70] = 0
    face = np.zeros(T.shape[:2], bool)
    face[32:38, 52:60] = True
    rend = np.zeros_like(T)
    rend[face] = 200
    frame = rw.RewriteFrame(img, rend, face, np.zeros_like(face))
    part = rc._crop_of(T, frame)
    assert part[0] == (50, 30, 70, 40)
    back = rw.paste_part(T, part)
    for x, y in zip(dataclasses.astuple(frame), dataclasses.astuple(back)):
        np.testing.assert_array_equal(x, y)
    unchanged = rw.RewriteFrame(T.copy(), np.zeros_like(T), np.zeros_like(face),
                                np.zeros_like(face))
    assert rc._crop_of(T, unchanged) is None
    np.testing.assert_array_equal(rw.paste_part(T, None).image, T)


def test_frame_meshes_are_the_frame_meshes_a_chunk_at_a_time(quick_model):
    """FrameMeshes serves every frame of a track as model.synthesize of that frame, C-contiguous,
    across chunks, on another thread, and for a track whose identity changes (synthesised
    whole); it never holds a clip-sized array for a track with one identity."""
    import threading
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    m = quick_model
    F = 2 * frame_meshes.MESH_CHUNK + 3  # the last chunk partial
    ident = np.tile(rng.normal(size=m.ranks[0]), (F, 1))
    expr = rng.normal(size=(F, m.ranks[1]))
    moving = ident + 0.1 * rng.normal(size=ident.shape)
    tracks = {kind: SimpleNamespace(weights={"identity": w, "expression": expr},
                                    mode_names=m.mode_names)
              for kind, w in (("new", ident), ("target", moving))}
    fm = frame_meshes.FrameMeshes(m, tracks, F)
    for kind, w in (("new", ident), ("target", moving)):
        for i in list(range(F)) + [0, F - 1, 5]:
            V = fm.frame(kind, i)
            assert V.flags.c_contiguous and V.shape == (m.n_vertices, 3)
            np.testing.assert_allclose(V, m.synthesize({"identity": w[i], "expression": expr[i]}),
                                       rtol=0, atol=1e-12)
    fm.frame("new", F - 1)
    held = {kind: dict(chunks) for kind, chunks in fm._chunks.items()}
    assert len(held["new"][F - 3]) == 3  # the last chunk, partial
    assert len(held["new"]) == frame_meshes.CHUNKS_KEPT  # and one other
    assert list(held["target"]) == [0] and len(held["target"][0]) == F  # the whole clip
    seen = []
    t = threading.Thread(target=lambda: seen.append(fm.frame("new", F - 2).copy()))
    t.start()
    t.join()
    np.testing.assert_allclose(seen[0], m.synthesize({"identity": ident[F - 2],
                                                      "expression": expr[F - 2]}), atol=1e-12)
    assert "new" in fm and "source" not in fm


def test_frame_meshes_make_each_chunk_once_for_two_threads(quick_model, monkeypatch):
    """Two threads asking for alternate frames (as the two-thread render does) share each
    chunk's product: one product per chunk, not one per thread; the meshes are those of one
    thread alone."""
    import threading
    from types import SimpleNamespace

    rng = np.random.default_rng(4)
    m = quick_model
    F = 3 * frame_meshes.MESH_CHUNK + 6  # even: each thread asks for F / 2 frames
    ident = np.tile(rng.normal(size=m.ranks[0]), (F, 1))
    expr = rng.normal(size=(F, m.ranks[1]))
    track = SimpleNamespace(weights={"identity": ident, "expression": expr},
                            mode_names=m.mode_names)
    alone = frame_meshes.FrameMeshes(m, {"new": track}, F)
    want = [alone.frame("new", i).copy() for i in range(F)]
    fm = frame_meshes.FrameMeshes(m, {"new": track}, F)
    basis = fm.basis("new")
    made = []
    real = type(basis).meshes
    monkeypatch.setattr(type(basis), "meshes",
                        lambda self, frames: made.append(int(frames[0])) or real(self, frames))
    got, gate = {}, threading.Barrier(2, timeout=60)

    def render(first):
        for i in range(first, F, 2):
            gate.wait()            # the two threads a frame apart, as the render's
            got[i] = fm.frame("new", i).copy()

    threads = [threading.Thread(target=render, args=(k,), daemon=True) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert sorted(got) == list(range(F))
    assert sorted(made) == list(range(0, F, frame_meshes.MESH_CHUNK))
    for i in range(F):
        np.testing.assert_array_equal(got[i], want[i])


def test_frame_meshes_shared_by_many_threads_in_any_order():
    """Eight threads asking for frames of two kinds in random order across chunk boundaries,
    some products failing: every mesh is its own frame's (a chunk evicted while a thread
    holds a view of it included), a failure reaches only the thread whose product failed,
    and no thread is left waiting."""
    import random
    import threading
    import time
    from types import SimpleNamespace

    n, lock = 5 * frame_meshes.MESH_CHUNK + 3, threading.Lock()

    class Basis:                # frame i's mesh all i; slow and sometimes failing products
        modes_left, rng, failing = 1, random.Random(0), True

        def meshes(self, rows):
            with lock:
                wait, fail = self.rng.random() * 2e-3, self.failing and self.rng.random() < 0.05
            time.sleep(wait)
            if fail:
                raise MemoryError("a product failed")
            return np.repeat(np.asarray(rows, float), 12).reshape(len(rows), 4, 3)

    track = SimpleNamespace(weights={"a": np.zeros((n, 1))}, mode_names=("a",))
    model = SimpleNamespace(mode_names=("a",), clip_basis=lambda weights: Basis())
    fm = frame_meshes.FrameMeshes(model, {"new": track, "target": track}, n)
    wrong, failed, done = [], [], []

    def ask(seed):
        rng, held = random.Random(seed), []
        for _ in range(150):
            i, kind = rng.randrange(n), rng.choice(["new", "target"])
            try:
                held.append((i, fm.frame(kind, i)))
            except MemoryError:
                failed.append(i)
            except Exception as exc:  # noqa: BLE001 - a wrong chunk's row out of range
                wrong.append(repr(exc))
            time.sleep(rng.random() * 1e-4)
        wrong.extend(i for i, V in held if not (V == i).all())
        done.append(seed)

    threads = [threading.Thread(target=ask, args=(k,), daemon=True) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not any(t.is_alive() for t in threads) and sorted(done) == list(range(8))
    assert wrong == [] and failed
    Basis.failing = False       # the products after the threads: none fails
    assert all((fm.frame("new", i) == i).all() for i in range(n))


def test_defaults_agree():
    import inspect

    from facetransfer import demo
    from facetransfer.rewrite_options import RewriteOptions

    # the demo's options default to RewriteOptions()'s
    assert inspect.signature(demo.run_demo).parameters["options"].default is None
    assert RewriteOptions().speed == presets.DEFAULT_SPEED
    assert inspect.signature(tp.plan_transfer).parameters["speed"].default == presets.DEFAULT_SPEED


@pytest.mark.parametrize("workers,processes", [(1, False), (2, False), (2, True)])
def test_parts_paste_to_the_whole_frames(quick_model, topo, synthetic, workers, processes):
    """``rewrite_frame_parts`` (what ``transfer`` writes from) gives each frame's
    face box, whose composite pasted by ``rewrite.paste_image`` is the whole frame's image
    to the bit, with whether a face was rendered; on one thread, two, or forked processes."""
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    lost = new.lost.copy()
    lost[1] = True                       # a frame without a face: None, the frame itself
    new = dataclasses.replace(new, lost=lost)

    def frames(parts):
        rewrite = rc.rewrite_frame_parts if parts else rc.rewrite_frames
        return list(rewrite(fb, tb, new, quick_model, mouth_source=rc.MouthSource(fa, ta),
                            topo=topo, run=rc.RenderRun(workers=workers, processes=processes)))

    whole, parts = frames(False), frames(True)
    assert len(parts) == len(whole) == new.n_frames and parts[1] is None
    assert all(p is not None and len(p[0]) == 4 for i, p in enumerate(parts) if i != 1)
    for i, (w, p) in enumerate(zip(whole, parts)):
        image, face = rw.paste_image(np.asarray(fb[i]), p)
        np.testing.assert_array_equal(image, w.image)
        assert face == bool(w.face_mask.any()) and face == (i != 1)
