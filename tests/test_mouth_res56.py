"""The mouth texture function lifted at a size that follows the face (§6), within a memory bound.

The performance-driven mouth texture of §6 used to be lifted into the whole UV atlas at a fixed
256²: on a 1080p face one mouth texel spans ~3 screen pixels, on a 4K face ~6, so the drawn
mouth lost the footage's detail. ``tex_size="auto"`` (:func:`facetransfer.texture.face.
mouth_layout`) lifts only the mouth's square of the UV layout at a side that gives about one
texel per screen pixel, as float16, within :data:`~facetransfer.texture.face.MOUTH_MAX_BYTES`.

The synthetic footage here paints a fine checker over the mouth's UV region of the face texture
and renders it with the project's renderer at three sizes: the texture function's texture,
drawn back on the same mesh and camera, must keep the checker where 256² loses it.
"""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import topology
from facetransfer.render import look_at_weak_perspective, render
from facetransfer.texture import face as ftex
from facetransfer.track import Track
from facetransfer.track.project import project_landmarks

LABELS = ["neutral", "open", "smile"]


def _checker_texture(model, topo, uvs, period_uv: float, T: int = 4096) -> np.ndarray:
    """The model's default texture (grey) with a black-and-white checker of ``period_uv`` UV
    units painted over the mouth's UV box, ``(T, T, 3) uint8``."""
    tex = np.full((T, T, 3), 128, np.uint8)
    box = uvs[np.unique(topo.faces[topo.mouth_faces])]
    lo, hi = box.min(0) - 0.02, box.max(0) + 0.02
    yy, xx = np.mgrid[0:T, 0:T]
    u, v = xx / (T - 1), 1 - yy / (T - 1)
    inside = (u >= lo[0]) & (u <= hi[0]) & (v >= lo[1]) & (v <= hi[1])
    check = ((np.floor(u / period_uv) + np.floor(v / period_uv)) % 2).astype(bool)
    tex[inside & check] = 230
    tex[inside & ~check] = 30
    return tex


def _scene(model, size: int, period_px: float):
    """Frames of ``LABELS`` at ``size``² with the mouth's checker ``period_px`` screen pixels
    wide, their track, the topology, the closed UVs and the neutral frame's camera."""
    topo = topology.mesh_topology(model)
    uvs = np.vstack([model.uvs, model.uvs[topo.mouth_loop].mean(0)])
    wid = model.training_weights("identity", "id03")
    es = [model.training_weights("expression", lab) for lab in LABELS]
    cam = look_at_weak_perspective(model.synthesize(model.default_weights()), (size, size),
                                   fill=0.8)
    n = len(es)
    tr = Track(fps=25.0, frame_size=(size, size), rotation=np.tile(np.eye(3), (n, 1, 1)),
               scale=np.full(n, cam.scale), translation=np.tile(cam.translation, (n, 1)),
               weights={"identity": np.tile(wid, (n, 1)), "expression": np.array(es)},
               landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n), lost=np.zeros(n, bool),
               model_hash=model.content_hash, mode_names=model.mode_names, source="synthetic")
    ppu = ftex._mouth_pixels_per_uv(model, tr, topo, uvs, np.arange(n))
    tex = _checker_texture(model, topo, uvs, period_px / ppu)
    frames = np.array([render(topology.close_mouth(model.synthesize(tr.weights_at(i)), topo),
                              topo.faces, tr.camera(i), (size, size), uvs=uvs, texture=tex,
                              shading="none", background=np.zeros((size, size, 3), np.uint8)
                              ).image for i in range(n)])
    return frames, project_landmarks(tr, model), topo, ppu


def _lips_mask(model, topo, track, i: int, size: int) -> np.ndarray:
    """The pixels of frame ``i`` the lips' triangles (mouth's, not the fan) cover, eroded."""
    import cv2

    fan = np.zeros(len(topo.faces), bool)
    fan[topo.mouth_fan] = True
    mf = topo.mouth_faces[~fan[topo.mouth_faces]]
    xy = track.camera(i).project(model.synthesize(track.weights_at(i)))
    mask = np.zeros((size, size), np.uint8)
    for f in topo.faces[mf]:
        cv2.fillConvexPoly(mask, np.rint(xy[f]).astype(np.int32), 1)
    return cv2.erode(mask, np.ones((5, 5), np.uint8)).astype(bool)


def _redrawn(model, topo, track, fn, i: int, size: int) -> np.ndarray:
    """The function's texture for frame ``i``'s attributes drawn on its mesh and camera."""
    from facetransfer.texture.function import attribute_vector

    V = topology.close_mouth(model.synthesize(track.weights_at(i)), topo)
    tex = fn.texture(attribute_vector(model, track.weights_at(i)))
    return render(V, topo.faces, track.camera(i), (size, size), uvs=fn.uvs, texture=tex,
                  shading="none", background=np.zeros((size, size, 3), np.uint8)).image


def _psnr(a, b, mask) -> float:
    d = ((np.asarray(a, float) - np.asarray(b, float)) ** 2)[mask]
    return float(10 * np.log10(255.0 ** 2 / max(d.mean(), 1e-12)))


# ------------------------------------------------------------------------- the size and memory
def test_the_side_follows_the_texels_the_face_asks_for_within_the_memory_bound():
    """``mouth_tex_size``: a multiple of 32 at least the texels asked for (up to the cap), the
    frames' textures within MOUTH_MAX_BYTES at 8 bytes a texel, frames cut before the side."""
    sizes = [ftex.mouth_tex_size(t, 120) for t in (20, 100, 230, 450, 700, 5000)]
    sides = [T for T, _ in sizes]
    assert sides == sorted(sides) and sides[0] == 32 and sides[1] == 128 and sides[2] == 256
    for (T, frames), t in zip(sizes, (20, 100, 230, 450, 700, 5000)):
        assert frames * T * T * 8 <= ftex.MOUTH_MAX_BYTES
        assert T % 32 == 0 and T <= ftex.MOUTH_MAX_TEX
        if frames == 120:
            assert T >= t
    # 450 texels: 448 would leave 83 frames (>= MOUTH_MIN_FRAMES): the side kept, frames cut
    assert ftex.mouth_tex_size(450, 120) == (480, int(ftex.MOUTH_MAX_BYTES // (480 ** 2 * 8)))
    # a huge face: MOUTH_MIN_FRAMES frames kept, the side shrunk to fit
    T, frames = ftex.mouth_tex_size(5000, 120)
    assert frames == ftex.MOUTH_MIN_FRAMES and (T + 32) ** 2 * 8 * frames > ftex.MOUTH_MAX_BYTES
    # fewer frames than the minimum: all of them, never more than given
    assert ftex.mouth_tex_size(100, 3) == (128, 3)


@pytest.mark.parametrize("size", [256, 1024])
def test_the_layout_grows_with_the_face_and_covers_the_drawn_mouth(quick_model, size):
    """``mouth_layout``: the square's side grows with the frame (the face's pixels), a texel
    spans at most one screen pixel, and every triangle drawn from the mouth's texture (its own
    and the gain's ring, :func:`facetransfer.mouth.mouth_ring_faces`) lies inside it."""
    from facetransfer.mouth import mouth_ring_faces

    m = quick_model
    frames, track, topo, ppu = _scene(m, size, 4.0)
    uvs = np.vstack([m.uvs, m.uvs[topo.mouth_loop].mean(0)])
    lay = ftex.mouth_layout(m, track, topo, uvs, np.arange(len(frames)))
    assert lay.pixels_per_uv == pytest.approx(ppu)
    assert lay.texel_pixels <= ftex.MOUTH_TEXEL_PIXELS
    # the old whole atlas at 256: one texel over ppu / 255 pixels, more than one at 1024²
    assert (ppu / 255 > 1.5) == (size == 1024)
    drawn = mouth_ring_faces(topo)
    drawn[topo.mouth_faces] = True
    c = lay.crop(uvs)[np.unique(topo.faces[drawn])]
    assert c.min() >= 0 and c.max() <= 1
    small = ftex.mouth_layout(m, track, topo, uvs, np.arange(len(frames)))
    assert small == lay   # the same frames: the same layout


# -------------------------------------------------------------------------- detail kept
def test_a_large_faces_fine_mouth_detail_survives_the_texture_function(quick_model):
    """A checker of 4-pixel squares painted over the mouth of a 2048² face (~1275 screen pixels
    per UV unit, the default model's 4K face has ~1480): the function's texture redrawn on the
    frame's mesh keeps it (auto, 384², 17.2 dB, 75 % of the footage's contrast) where the whole
    atlas at 256² (one texel over 5 pixels) averages it towards grey (8.3 dB, 38 %)."""
    m = quick_model
    size = 2048
    frames, track, topo, ppu = _scene(m, size, 4.0)
    auto = ftex.mouth_texture_function(m, frames, track, topo, tex_size="auto")
    old = ftex.mouth_texture_function(m, frames, track, topo)       # tex_size=256
    assert auto.function.textures.dtype == np.float16
    assert auto.function.textures.nbytes + auto.function.weights.nbytes <= ftex.MOUTH_MAX_BYTES
    i = 0
    mask = _lips_mask(m, topo, track, i, size)
    assert mask.sum() > 2000
    truth = frames[i]
    p_auto = _psnr(_redrawn(m, topo, track, auto, i, size), truth, mask)
    p_old = _psnr(_redrawn(m, topo, track, old, i, size), truth, mask)
    print(f"ppu {ppu:.0f}, T {auto.function.textures.shape[1]}: PSNR auto {p_auto:.1f} dB, "
          f"256 {p_old:.1f} dB")
    # the checker's contrast (std of the lips' pixels): the footage's, kept and lost
    sd = [float(img[mask].astype(float).std()) for img in
          (truth, _redrawn(m, topo, track, auto, i, size), _redrawn(m, topo, track, old, i, size))]
    print("contrast truth / auto / 256", sd)
    assert p_auto > 15.0 and p_auto > p_old + 6.0
    assert sd[1] > 0.65 * sd[0] and sd[2] < 0.5 * sd[0]


def test_a_small_face_lifts_no_coarser_than_before(quick_model):
    """A 256² face (one old texel ~1.4 px): the auto square is at least as fine as the whole
    atlas at 256² at the mouth (MOUTH_MIN_DENSITY), and the redrawn mouth as close to the
    footage (no worse than 0.1 dB)."""
    m = quick_model
    size = 256
    frames, track, topo, ppu = _scene(m, size, 4.0)
    auto = ftex.mouth_texture_function(m, frames, track, topo, tex_size="auto")
    old = ftex.mouth_texture_function(m, frames, track, topo)
    T = auto.function.textures.shape[1]
    uvs = np.vstack([m.uvs, m.uvs[topo.mouth_loop].mean(0)])
    lay = ftex.mouth_layout(m, track, topo, uvs, np.arange(len(frames)))
    assert T == lay.tex_size and (T - 1) / lay.side >= 255
    mask = _lips_mask(m, topo, track, 0, size)
    p_auto = _psnr(_redrawn(m, topo, track, auto, 0, size), frames[0], mask)
    p_old = _psnr(_redrawn(m, topo, track, old, 0, size), frames[0], mask)
    print(f"256²: PSNR auto {p_auto:.1f} dB, 256 {p_old:.1f} dB")
    assert p_auto >= p_old - 0.1


def test_tex_size_must_be_a_size_or_auto(quick_model):
    from facetransfer.errors import RewriteError

    m = quick_model
    frames, track, topo, _ = _scene(m, 128, 4.0)
    with pytest.raises(RewriteError, match="'auto'"):
        ftex.mouth_texture_function(m, frames, track, topo, tex_size="big")


def test_the_transfers_mouth_function_lifts_at_the_faces_size(monkeypatch):
    """``TransferPlan.mouth_function`` (the CLI's path, ``video_transfer._lift_mouth``) asks for
    ``tex_size="auto"`` of the target's frames and of a resampled mouth source alike; a size
    given is passed on."""
    from types import SimpleNamespace

    from facetransfer import transfer_plan as tp

    seen = []
    monkeypatch.setattr(tp, "mouth_texture_function",
                        lambda *a, **kw: seen.append(("target", kw.get("tex_size"))))
    monkeypatch.setattr(tp, "timeline_mouth_function",
                        lambda *a, **kw: seen.append(("timeline", kw.get("tex_size"))))
    track = SimpleNamespace(n_frames=3)
    own = SimpleNamespace(texture_frames=np.zeros((3, 4, 4, 3), np.uint8), texture_track=track)
    other = SimpleNamespace(texture_frames=None, texture_track=None, mouth_frames=None,
                            mouth_track=track, mouth_index=np.arange(3), n_frames=3)
    tp.TransferPlan.mouth_function(own, None)
    tp.TransferPlan.mouth_function(other, None)
    tp.TransferPlan.mouth_function(own, None, tex_size=64)
    assert seen == [("target", "auto"), ("timeline", "auto"), ("target", 64)]


def test_a_mesh_without_a_mouth_lays_out_the_whole_atlas_at_the_old_density(quick_model):
    """No mouth triangles (a model whose mesh has no mouth gap): the square is the whole UV
    layout at 256 texels per UV unit (the old 256² atlas), not an error."""
    import dataclasses

    m = quick_model
    frames, track, topo, _ = _scene(m, 256, 4.0)
    bare = dataclasses.replace(topo, mouth_faces=np.zeros(0, np.int64))
    uvs = np.vstack([m.uvs, m.uvs[topo.mouth_loop].mean(0)])
    lay = ftex.mouth_layout(m, track, bare, uvs, np.arange(len(frames)))
    assert lay.pixels_per_uv == 0.0
    c = lay.crop(uvs)
    assert c.min() >= 0 and c.max() <= 1 and lay.side >= float(np.ptp(uvs, axis=0).max())
    assert lay.tex_size == 32 * int(np.ceil(256 * lay.side / 32))
