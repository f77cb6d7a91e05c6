"""Tests of facetransfer.rewrite: mesh topology, blending, and a synthetic transfer with truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer import frame_meshes
from facetransfer import rewrite as rw
from facetransfer import rewrite_clip as rc
from facetransfer import composite
from facetransfer import mouth
from facetransfer.texture import face as ftex
from facetransfer.track import obtain
from facetransfer import rewrite_options as rwo
from facetransfer import topology
from facetransfer import transfer_plan as tp
from facetransfer.render import WeakPerspective, look_at_weak_perspective, render, rotation_from_euler
from facetransfer.track import Track
from facetransfer.track.project import project_landmarks
from facetransfer.texture.function import nearest_frames
from facetransfer.transfer import recombine

SIZE = (128, 128)


def psnr(a, b, mask=None) -> float:
    d = (np.asarray(a, float) - np.asarray(b, float)) ** 2
    if mask is not None:
        d = d[mask]
    return float(10 * np.log10(255.0 ** 2 / max(d.mean(), 1e-12)))


@pytest.fixture(scope="module")
def topo(quick_model):
    return topology.mesh_topology(quick_model)


@pytest.fixture(scope="module")
def face_texture(quick_model):
    from facetransfer.texture import default_face_texture

    return default_face_texture(quick_model, 256)


def render_clip(model, topo, texture, identity, expressions, yaws, *, seed, size=SIZE):
    """Frames of ``identity`` performing ``expressions`` (closed mouth textured too) and the
    truth track. Background: smooth noise."""
    import cv2

    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur((rng.random((size[1], size[0], 3)) * 255).astype(np.uint8), (0, 0), 2)
    wid = model.training_weights("identity", identity)
    cam0 = look_at_weak_perspective(model.synthesize(model.default_weights()), size, fill=0.75)
    uvs = np.vstack([model.uvs, model.uvs[topo.mouth_loop].mean(0)])
    frames, R, w_e = [], [], []
    for e, yaw in zip(expressions, yaws):
        Rf = rotation_from_euler(yaw, 0, 0)
        V = topology.close_mouth(model.synthesize({"identity": wid, "expression": e}), topo)
        cam = WeakPerspective(cam0.scale, Rf, cam0.translation)
        frames.append(render(V, topo.faces, cam, size, uvs=uvs, texture=texture,
                             shading="none", background=bg).image)
        R.append(Rf)
        w_e.append(e)
    n = len(frames)
    tr = Track(fps=25.0, frame_size=size, rotation=np.array(R), scale=np.full(n, cam0.scale),
               translation=np.tile(cam0.translation, (n, 1)),
               weights={"identity": np.tile(wid, (n, 1)), "expression": np.array(w_e)},
               landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n), lost=np.zeros(n, bool),
               model_hash=model.content_hash, mode_names=model.mode_names, source="synthetic")
    return np.array(frames), project_landmarks(tr, model)


@pytest.fixture(scope="module")
def synthetic(quick_model, topo, face_texture):
    """A's expressions (source, id01), B's footage (target, id03, neutral), and the truth:
    B performing A's expressions with B's pose and background."""
    m = quick_model
    labels = ["neutral", "open", "smile", "surprise", "pucker"]
    e_a = [m.training_weights("expression", l) for l in labels]
    e_b = [m.training_weights("expression", "neutral")] * len(labels)
    yaw_a, yaw_b = [0, 6, 12, 6, -4], [-5, 0, 5, 10, 3]
    fa, ta = render_clip(m, topo, face_texture, "id01", e_a, yaw_a, seed=1)
    fb, tb = render_clip(m, topo, face_texture, "id03", e_b, yaw_b, seed=2)
    truth, _ = render_clip(m, topo, face_texture, "id03", e_a, yaw_b, seed=2)
    return fa, ta, fb, tb, truth


# --------------------------------------------------------------------------------- topology
def test_boundary_loops_of_a_square_and_a_hole():
    # a 3x3 grid of vertices, 8 triangles: one outer loop of 8 vertices
    faces = []
    for y in range(2):
        for x in range(2):
            a, b, c, d = 3 * y + x, 3 * y + x + 1, 3 * y + x + 3, 3 * y + x + 4
            faces += [[a, b, d], [a, d, c]]
    loops = topology.boundary_loops(np.array(faces))
    assert len(loops) == 1 and sorted(loops[0].tolist()) == [0, 1, 2, 3, 5, 6, 7, 8]
    # removing the centre vertex's triangles leaves no inner loop (the centre is gone), the
    # grid without its two centre triangles gets a hole
    loops = topology.boundary_loops(np.array(faces[:3] + faces[4:]))
    assert len(loops) == 1  # still one boundary (the notch merges with the outer loop)


def test_mesh_topology_finds_mouth_and_eyes(quick_model, topo):
    assert topo.mouth_loop.size > 10
    assert len(topo.eye_loops) == 2
    assert topo.faces.shape[0] == quick_model.faces.shape[0] + topo.mouth_loop.size
    # the fan closes the gap: in the closed mesh no mouth loop vertex is on the boundary
    loops = topology.boundary_loops(topo.faces)
    on_boundary = set(np.concatenate(loops).tolist())
    assert not on_boundary & set(topo.mouth_loop.tolist())
    assert len(loops) == 3  # outer boundary and two eye holes
    V = quick_model.synthesize(quick_model.default_weights())
    Vc = topology.close_mouth(V, topo)
    np.testing.assert_allclose(Vc[-1], V[topo.mouth_loop].mean(0))
    np.testing.assert_array_equal(Vc[:-1], V)
    with pytest.raises(Exception, match="vertices must be"):
        topology.close_mouth(V[:10], topo)


def test_inside_polygon_equals_matplotlib():
    """The lips' polygon test decides as matplotlib's Path.contains_points, vertices and
    edge midpoints included."""
    from matplotlib.path import Path

    rng = np.random.default_rng(12)
    for t in range(30):
        k = int(rng.integers(3, 14))
        ang = np.sort(rng.random(k)) * 2 * np.pi
        poly = np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(0.3, 1, (k, 1))
        if t % 3 == 0:  # self-intersecting
            poly = rng.normal(size=(k, 2))
        pts = rng.uniform(-1.2, 1.2, (500, 2))
        pts[:k] = poly
        pts[k:2 * k] = (poly + np.roll(poly, -1, 0)) / 2
        got = topology.inside_polygon(poly, pts)
        np.testing.assert_array_equal(got, Path(poly).contains_points(pts))
        assert 0 < got.sum() < 500


# --------------------------------------------------------------------------------- blending
def test_membrane_mouth_equals_the_membrane_on_the_whole_crop_inside_the_face():
    """The mouth's membrane (without a ring of skin to fit a gain on, and so with no ring) on
    its box, in place, gives the whole crop's blend inside the face (all the face's own blend
    reads of it), also with the box clipped by the crop's edge."""
    rng = np.random.default_rng(21)
    H, W = 90, 120
    T = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    face_img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    face_mask = np.zeros((H, W), bool)
    face_mask[10:85, 5:110] = True
    mouth_img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    for box in ((slice(50, 70), slice(40, 80)), (slice(78, 85), slice(5, 30))):
        mask = np.zeros((H, W), bool)
        mask[box] = True
        want = composite.membrane_blend(composite.over(T, face_img, face_mask), mouth_img, mask,
                                        feather=3.0, outlier=None)
        got = mouth._membrane_mouth(T, face_img.copy(), face_mask, mouth_img, mask, 3.0)
        np.testing.assert_array_equal(got[face_mask], want[face_mask])
        got = mouth.blend_mouth(T, face_img.copy(), face_mask, mouth_img, mask, None, 3.0)
        np.testing.assert_array_equal(got[face_mask], want[face_mask])
        assert (got[mask] != face_img[mask]).any()


def test_membrane_blend_outside_exact_and_recovers_offset():
    yy, xx = np.mgrid[0:60, 0:70]
    T = np.stack([60 + 2 * xx, 50 + 2 * yy, 120 + xx - yy], axis=-1).astype(np.uint8)
    mask = np.zeros((60, 70), bool)
    mask[15:45, 20:50] = True
    # a source that is the target plus a constant: blending removes the constant
    S = np.clip(T.astype(int) + 40, 0, 255).astype(np.uint8)
    out = composite.membrane_blend(T, S, mask, feather=0)
    np.testing.assert_array_equal(out[~mask], T[~mask])
    assert np.abs(out[mask].astype(int) - T[mask].astype(int)).mean() < 1.0
    np.testing.assert_array_equal(composite.membrane_blend(T, S, np.zeros_like(mask)), T)


# --------------------------------------------------------------------------------- rewrite
@pytest.mark.parametrize("blend,texture,threshold", [("none", "frame", 30.0),
                                                     ("fast", "frame", 27.5),
                                                     ("fast", "constant", 27.5),
                                                     ("poisson", "constant", 27.5)])
def test_synthetic_transfer_matches_truth(quick_model, topo, synthetic, blend, texture,
                                          threshold):
    """B performing A's expressions: our rewrite of B's footage with A's track against the
    rendering of the truth. Measured (quick model, 128 px, face region, 5 frames): none
    31.4-48 dB, fast 29.1-35.8 dB, poisson 29.9-38 dB, against 22.7-30.8 dB for the untouched
    target; thresholds leave >= 1.6 dB margin."""
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    outs = list(rc.rewrite_frames(fb, tb, new, quick_model,
                                  mouth_source=rc.MouthSource(fa, ta), topo=topo,
                                  options=rwo.RewriteOptions(texture=texture, blend=blend)))
    assert len(outs) == len(fb)
    for i, o in enumerate(outs):
        assert o.face_mask.sum() > 2000
        assert psnr(o.image, truth[i], o.face_mask) > threshold, i
        # outside the (feathered, dilated) face mask: the target frame, exactly
        import scipy.ndimage as ndi

        grown = ndi.binary_dilation(o.face_mask, iterations=4)
        np.testing.assert_array_equal(o.image[~grown], fb[i][~grown])
    # the open mouth (frame 1) really changes the target: the truth differs from the target
    assert psnr(fb[1], truth[1], outs[1].face_mask) < psnr(outs[1].image, truth[1],
                                                           outs[1].face_mask) - 3
    assert outs[1].mouth_mask.sum() > 50  # the mouth texture came from the source


def test_eye_holes_show_the_target(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    o = next(rc.rewrite_frames(fb, tb, new, quick_model, mouth_source=rc.MouthSource(fa, ta),
                               options=rwo.RewriteOptions(blend="none", eyes="target"),
                               topo=topo))
    # pixels inside the face's outline but not covered by the mesh: the eye holes
    import scipy.ndimage as ndi

    holes = ndi.binary_fill_holes(o.face_mask) & ~o.face_mask
    assert holes.sum() > 10
    np.testing.assert_array_equal(o.image[holes], fb[0][holes])
    # with the eyes of the new performance (the default, facetransfer.eyes) they are rendered
    e = next(rc.rewrite_frames(fb, tb, new, quick_model, mouth_source=rc.MouthSource(fa, ta),
                               options=rwo.RewriteOptions(blend="none"), topo=topo))
    assert e.face_mask[holes].all()


def test_lost_frames_keep_the_original(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    ta_lost = dataclasses.replace(ta, lost=np.array([False, True, False, False, True]))
    new = recombine(tb, expression=ta_lost)
    outs = list(rc.rewrite_frames(fb, tb, new, quick_model,
                                  mouth_source=rc.MouthSource(fa, ta_lost), topo=topo))
    for i in (1, 4):
        np.testing.assert_array_equal(outs[i].image, fb[i])
        assert not outs[i].face_mask.any()
    assert not np.array_equal(outs[2].image, fb[2])


def test_rewrite_bad_input(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    with pytest.raises(rwo.RewriteError, match="texture"):
        list(rc.rewrite_frames(fb, tb, new, quick_model,
                               options=rwo.RewriteOptions(texture="bogus")))
    with pytest.raises(rwo.RewriteError, match="only 2"):
        list(rc.rewrite_frames(fb[:2], tb, new, quick_model))
    with pytest.raises(rwo.RewriteError, match="64x64"):
        list(rc.rewrite_frames(fb[:, :64, :64], tb, new, quick_model))
    with pytest.raises(rwo.RewriteError, match="blend"):
        rw.rewrite_frame(fb[0], quick_model.synthesize(tb.weights_at(0)), tb.camera(0), topo,
                         rw.FrameTextures(ftex.FaceTexture(fb[0], np.zeros((topo.n_closed, 2)))),
                         blending=rwo.BlendOptions("magic"))


def test_landmark_track_recovers_pose_and_marks_lost(quick_model):
    """The landmark-only fallback on exact projected landmarks of a known performance."""
    m = quick_model
    n = 4
    w = {"identity": np.tile(m.training_weights("identity", "id02"), (n, 1)),
         "expression": np.array([m.training_weights("expression", l)
                                 for l in ("neutral", "smile", "open", "neutral")])}
    R = np.array([rotation_from_euler(y, 0, 0) for y in (0, 5, 10, -5)])
    tr = Track(fps=25.0, frame_size=(200, 200), rotation=R, scale=np.full(n, 6.0),
               translation=np.tile([100.0, 100.0], (n, 1)), weights=w,
               landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n), lost=np.zeros(n, bool),
               model_hash=m.content_hash, mode_names=m.mode_names)
    L = project_landmarks(tr, m).landmarks2d.copy()
    L[3] = np.nan
    fit = obtain.landmark_track(m, L, fps=25.0, size=(200, 200))
    np.testing.assert_array_equal(fit.lost, [False, False, False, True])
    err = np.linalg.norm(fit.landmarks2d[:3] - L[:3], axis=-1).mean()
    assert err < 2.5  # pixels, on a face ~110 px wide (measured 1.5)
    np.testing.assert_allclose(fit.scale[:3], 6.0, rtol=0.1)
    with pytest.raises(Exception, match="no face"):
        obtain.landmark_track(m, np.full((2, 68, 2), np.nan), fps=25.0, size=(200, 200))


def test_nearest_frames_picks_closest_valid_row():
    bank = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [5.0, 5.0]])
    q = np.array([[0.9, 0.1], [0.1, 0.8], [4.0, 4.0]])
    np.testing.assert_array_equal(nearest_frames(q, bank), [1, 2, 3])
    valid = np.array([True, True, True, False])
    np.testing.assert_array_equal(nearest_frames(q, bank, valid), [1, 2, 1])
    with pytest.raises(rwo.RewriteError, match="all lost"):
        nearest_frames(q, bank, np.zeros(4, bool))


def test_parallel_rendering_is_deterministic(quick_model, topo, synthetic):
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    runs = [[o.image for o in rc.rewrite_frames(fb, tb, new, quick_model,
                                                mouth_source=rc.MouthSource(fa, ta), topo=topo,
                                                run=rc.RenderRun(workers=w))]
            for w in (1, 2)]
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("workers, processes", [(1, False), (2, False), (2, True)])
def test_a_render_started_later_gives_the_same_frames(quick_model, topo, synthetic, workers,
                                                      processes):
    """``rewrite_frames(run=RenderRun(start=k))``: frames k.. equal those of a whole render,
    here, on threads and in forked processes (a render continued after an interruption)."""
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    kw = dict(mouth_source=rc.MouthSource(fa, ta), topo=topo)
    whole = [o.image for o in rc.rewrite_frames(fb, tb, new, quick_model,
                                                run=rc.RenderRun(workers=1), **kw)]
    later = [o.image for o in rc.rewrite_frames(fb, tb, new, quick_model, run=rc.RenderRun(
        workers=workers, processes=processes, start=2), **kw)]
    assert len(later) == len(whole) - 2
    for a, b in zip(later, whole[2:]):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(rwo.RewriteError, match="outside"):
        next(rc.rewrite_frames(fb, tb, new, quick_model,
                               run=rc.RenderRun(start=len(whole) + 1), **kw))


def test_an_identity_ulps_apart_is_contracted_once(quick_model, topo, synthetic):
    """A source track whose identity differs by an ulp or two from frame to frame (resampled
    or filtered elsewhere) renders as its constant identity does, through one contracted
    basis; an identity that truly changes keeps every frame's own."""
    fa, ta, fb, tb, truth = synthetic
    new = recombine(tb, expression=ta)
    ident = ta.weights["identity"]
    nudged = ident * (1 + np.arange(len(ident))[:, None] * 2e-16)
    assert (nudged != ident[0]).any()
    ta2 = dataclasses.replace(ta, weights=dict(ta.weights, identity=nudged))
    kw = dict(topo=topo, run=rc.RenderRun(workers=1))
    exact = [o.image for o in rc.rewrite_frames(fb, tb, new, quick_model,
                                                mouth_source=rc.MouthSource(fa, ta), **kw)]
    near = [o.image for o in rc.rewrite_frames(fb, tb, new, quick_model,
                                               mouth_source=rc.MouthSource(fa, ta2), **kw)]
    for a, b in zip(exact, near):
        np.testing.assert_array_equal(a, b)
    meshes = frame_meshes.FrameMeshes(quick_model, {"source": ta2}, ta2.n_frames)
    assert meshes.basis("source").modes_left == 1
    moved = ident + np.linspace(0, 1e-3, len(ident))[:, None]
    assert (frame_meshes.constant_if_nearly(moved) == moved).all()
    assert (frame_meshes.constant_if_nearly(nudged) == ident[0]).all()


def test_erode_equals_scipy_binary_erosion():
    import scipy.ndimage as ndi

    rng = np.random.default_rng(0)
    for k in (1, 2, 3):
        m = ndi.binary_opening(rng.random((60, 80)) < 0.7)
        m[0, :] = True  # the image border counts as outside
        m[:, -1] = True
        np.testing.assert_array_equal(composite.erode_mask(m, k),
                                      ndi.binary_erosion(m, iterations=k))


def test_a_target_track_of_another_clip_is_said(quick_model, caplog):
    """A ``--target-track`` made from a video of another name than the target: one warning
    naming both (another clip of the same size drove the wrong face silently); a track of the
    same name, or of a renamed path in another folder, says nothing."""
    import logging

    from conftest import still_track

    tr = still_track(quick_model, 2, source="/clips/katie.mp4")
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        tp._warn_other_source(tr, "/elsewhere/katie.mp4", "target")
        assert not caplog.records
        tp._warn_other_source(tr, "d6.mp4", "target")
    assert [r.getMessage() for r in caplog.records] == [
        "target track of /clips/katie.mp4 was made from katie.mp4, not d6.mp4: if that is "
        "another clip, its motion drives the wrong face"]


def test_transfer_video_of_a_path_says_what_it_takes(tmp_path):
    """transfer_video("target.mp4", ...) failed with AttributeError "'str' object has no
    attribute 'performance'"."""
    from facetransfer.errors import RewriteError
    from facetransfer.video_transfer import transfer_video

    with pytest.raises(RewriteError, match=r"takes a TransferSources.*got str 't.mp4'.*"
                                           r"TransferSources.of\(target"):
        transfer_video("t.mp4", tmp_path / "out.mp4", object())
