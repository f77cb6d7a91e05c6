"""Texture lifting over a synthetic clip with exact truth (§6): lift_track, merge, texture function."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.datasets import FaceDataset
from facetransfer.model import build_model
from facetransfer.render import WeakPerspective, render
from facetransfer.synth import make_clip, random_performance
from facetransfer.texture import (TextureError, TextureFunction, attribute_vector,
                                  default_face_texture, lift_track, merge_textures,
                                  texture_to_uint8)

EXPRESSIONS = ("neutral", "smile", "open")


def _cap_dataset(nr=30, nc=26, n_id=3, seed=0) -> FaceDataset:
    """A face-like cap facing +z with small identity and expression variation, with UVs."""
    rng = np.random.default_rng(seed)
    U, Vv = np.meshgrid(np.linspace(-1.1, 1.1, nc), np.linspace(-1.2, 1.2, nr))
    base = np.stack([np.sin(U) * np.cos(0.8 * Vv), 1.3 * np.sin(0.8 * Vv),
                     np.cos(U) * np.cos(0.8 * Vv)], -1).reshape(-1, 3) * 10.0
    i = (np.arange(nr - 1)[:, None] * nc + np.arange(nc - 1)[None]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + nc + 1], 1), np.stack([i, i + nc + 1, i + nc], 1)])
    uvs = np.stack([(U.ravel() + 1.1) / 2.2, (Vv.ravel() + 1.2) / 2.4], 1)
    x, y = base[:, 0], base[:, 1]
    mouth = np.exp(-((y + 6) ** 2 + x**2) / 8.0)
    off = {"neutral": 0 * base, "smile": mouth[:, None] * np.stack([0.6 * np.sign(x), 0.8 + 0 * x, 0 * x], 1),
           "open": mouth[:, None] * np.array([0.0, -2.0, -0.5])}
    ids = [base * (1 + 0.05 * rng.normal(size=3)) for _ in range(n_id)]
    verts = np.stack([np.stack([b + off[e] for e in EXPRESSIONS]) for b in ids])
    return FaceDataset(verts, np.ones(verts.shape[:2], bool), ("identity", "expression"),
                       (tuple(f"id{k}" for k in range(n_id)), EXPRESSIONS), faces, uvs, None, None,
                       {"dataset": "test-cap"})


@pytest.fixture(scope="module")
def clip_and_model():
    model = build_model(_cap_dataset(), {"identity": 3, "expression": 3})
    tex = default_face_texture(model.uvs, size=128, seed=3)
    perf = random_performance(model, 10, seed=1, size=(200, 160), yaw_deg=15, pitch_deg=8)
    clip = make_clip(model, perf, texture=tex, background=(0, 0, 0))
    return model, clip, tex


def _psnr(a, b):
    return 10 * np.log10(255.0**2 / np.mean((a.astype(float) - b.astype(float)) ** 2))


def test_lift_track_merge_and_texture_function(clip_and_model):
    model, clip, tex = clip_and_model
    lt = lift_track(model, iter(clip.frames), clip.truth, tex_size=128, step=2)
    assert list(lt.frames) == [0, 2, 4, 6, 8] and lt.attributes.shape == (5, 3)
    merged = merge_textures(lt.lifted)
    seen = merged.weight > 0.2
    assert seen.mean() > 0.5
    # the synthetic frames are Lambert-shaded: the lifted texture is the known texture times a
    # shading factor in [ambient, 1]; where the face looks at the camera that factor is near 1
    ratio = merged.texture[seen].mean(axis=1) / np.maximum(tex[seen].astype(float).mean(axis=1), 1)
    assert 0.6 < np.median(ratio) <= 1.02

    # texture function at a training frame's attributes re-renders that frame closely
    tf = TextureFunction.from_lifted(lt.lifted, lt.attributes, k=3)
    i = 4
    w = {m: clip.truth.weights[m][i] for m in model.mode_names}
    V = model.synthesize(w)
    cam = WeakPerspective(clip.truth.scale[i], clip.truth.rotation[i], clip.truth.translation[i])
    t_i = texture_to_uint8(tf(attribute_vector(model, w)))
    r = render(V, model.faces, cam, (200, 160), uvs=model.uvs, texture=t_i, shading="none")
    m = r.raster.mask
    assert _psnr(r.image[m], clip.frames[i][m]) > 30.0  # measured about 37 dB
    # the merged texture (all frames, shading averaged) is close but not better than that
    r2 = render(V, model.faces, cam, (200, 160), uvs=model.uvs,
                texture=texture_to_uint8(merged.texture), shading="none")
    assert 25.0 < _psnr(r2.image[m], clip.frames[i][m]) <= _psnr(r.image[m], clip.frames[i][m]) + 0.5


def test_lift_track_rejects_mismatched_clip(clip_and_model):
    model, clip, _ = clip_and_model
    with pytest.raises(TextureError):
        lift_track(model, iter(clip.frames[:5]), clip.truth, tex_size=32)
    with pytest.raises(TextureError):
        lift_track(model, iter(np.concatenate([clip.frames, clip.frames[:1]])), clip.truth, tex_size=32)
    with pytest.raises(TextureError):
        lift_track(model, iter(clip.frames), clip.truth, tex_size=32, step=0)
    with pytest.raises(TextureError):
        attribute_vector(model, {"identity": np.zeros(3)})


def test_lift_merged_is_the_merge_of_lift_track_in_one_textures_memory(clip_and_model):
    """The merge taken as the frames come (lift_merged, TextureSum) is the weighted mean of
    every lifted frame (Σ w tex / Σ w over the known texels, within 1e-3 of a level), and its
    peak memory does not grow with the frames lifted, where lift_track's does."""
    import tracemalloc

    from facetransfer.texture import TextureSum, lift_merged

    from facetransfer.texture.merge import stack_lifted

    model, clip, _ = clip_and_model
    lt = lift_track(model, iter(clip.frames), clip.truth, tex_size=128, step=2)
    merged, used = lift_merged(model, iter(clip.frames), clip.truth, tex_size=128, step=2)
    assert used == len(lt.lifted) == 5
    # the weighted mean written out over the stacked textures (not through TextureSum)
    C, W = (a.astype(np.float64) for a in stack_lifted(lt.lifted))
    total = W.sum(0)
    known = total > 1e-6
    mean = (W[..., None] * C).sum(0)[known] / total[known][:, None]
    np.testing.assert_allclose(merged.weight, total, rtol=1e-5, atol=1e-5)
    assert known.sum() > 0.5 * known.size
    assert np.abs(merged.texture[known] - mean).max() < 1e-3
    assert np.abs(merge_textures(lt.lifted, fill="none").texture[known] - mean).max() < 1e-3
    sums = TextureSum()
    with pytest.raises(TextureError, match="at least one"):
        sums.merged()

    def peak(fn, n):
        frames = np.concatenate([clip.frames] * n)
        truth = _repeated(clip.truth, n)
        tracemalloc.start()
        fn(model, iter(frames), truth, tex_size=128, step=1)
        top = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return top

    one_texture = 128 * 128 * 16
    assert peak(lift_merged, 3) - peak(lift_merged, 1) < 2 * one_texture   # 20 more frames
    assert peak(lift_track, 3) - peak(lift_track, 1) > 15 * one_texture


def _repeated(truth, n: int):
    """``truth``'s frames ``n`` times over (as a track of a clip played ``n`` times)."""
    import dataclasses

    return dataclasses.replace(
        truth, rotation=np.concatenate([truth.rotation] * n),
        scale=np.concatenate([truth.scale] * n),
        translation=np.concatenate([truth.translation] * n),
        weights={m: np.concatenate([w] * n) for m, w in truth.weights.items()})
