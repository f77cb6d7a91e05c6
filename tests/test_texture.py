"""Tests of facetransfer.texture: lifting, merging, the texture function (§6), default texture."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from facetransfer.errors import ShapeError
from facetransfer.render import (WeakPerspective, look_at_weak_perspective, render,
                                 rotation_from_euler, sample_texture)
from facetransfer.texture import (TextureError, TextureFunction, UVAtlas, bake_texture,
                                  default_face_texture,
                                  fill_holes, fill_vertex_colors, lift_uv_texture,
                                  lift_vertex_colors, merge_textures, obliqueness_weight,
                                  texture_to_uint8, uv_atlas)


# --------------------------------------------------------------------------------------------
# small meshes
# --------------------------------------------------------------------------------------------

def uv_sphere(n_lat=24, n_lon=48):
    """Unit sphere, y up, seam duplicated so that per-vertex uvs are valid; outward normals."""
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(TH) * np.sin(PH), np.cos(TH), np.sin(TH) * np.cos(PH)], -1).reshape(-1, 3)
    UV = np.stack([PH / (2 * np.pi), 1 - TH / np.pi], -1).reshape(-1, 2)
    idx = np.arange(V.shape[0]).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    ok = np.linalg.norm(n, axis=1) > 1e-12
    F, n = F[ok], n[ok]
    if np.mean(np.einsum("ij,ij->i", n, V[F].mean(1))) < 0:
        F = F[:, ::-1]
    return V, F.astype(np.int64), UV


def grid(n=8, z=0.0, x0=-1.0, x1=1.0, uv_box=(0.0, 0.0, 1.0, 1.0)):
    """A square grid in the plane z facing +z (towards a frontal camera), uvs in ``uv_box``."""
    s = np.linspace(0, 1, n + 1)
    X, Y = np.meshgrid(x0 + (x1 - x0) * s, x0 + (x1 - x0) * s)
    V = np.stack([X, Y, np.full_like(X, z)], -1).reshape(-1, 3)
    U, W = np.meshgrid(s, s)
    u0, v0, u1, v1 = uv_box
    UV = np.stack([u0 + (u1 - u0) * U, v0 + (v1 - v0) * W], -1).reshape(-1, 2)
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return V, F.astype(np.int64), UV


def smooth_texture(T=128, seed=0):
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.integers(0, 255, (T, T, 3)).astype(np.uint8), (0, 0), 2.5)
    return cv2.normalize(t, None, 10, 245, cv2.NORM_MINMAX)


def psnr(a, b):
    mse = np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2)
    return 10 * np.log10(255.0**2 / mse)


# --------------------------------------------------------------------------------------------
# UV atlas
# --------------------------------------------------------------------------------------------

def test_atlas_texel_uv_convention_matches_render():
    """Interpolated uvs at texels are exactly u = col/(T-1), v = 1 - row/(T-1)."""
    V, F, UV = grid(4)
    T = 17
    a = UVAtlas(F, UV, T)
    assert a.mask.all() and a.n_texels == T * T
    uv = a.interpolate(UV)
    rows, cols = np.divmod(np.arange(T * T), T)
    np.testing.assert_allclose(uv[:, 0], cols / (T - 1), atol=1e-12)
    np.testing.assert_allclose(uv[:, 1], 1 - rows / (T - 1), atol=1e-12)
    # and render's sampler reads the texel itself back: exact round trip
    tex = smooth_texture(T)
    np.testing.assert_allclose(sample_texture(tex, uv).reshape(T, T, 3), tex, atol=1e-3)
    np.testing.assert_allclose(a.texel_bary.sum(-1), 1, atol=1e-6)


def test_atlas_interpolation_is_each_texels_barycentric_sum():
    """The interpolation (a sparse matrix made once per atlas) is, texel by texel, its
    triangle's corners weighted by its barycentric coordinates, for any values, twice."""
    V, F, UV = grid(6)
    a = UVAtlas(F, UV, 33)
    rng = np.random.default_rng(4)
    for X in (rng.normal(size=(len(UV), 3)), rng.normal(size=(len(UV), 5))):
        tri = a.texel_triangles
        bary = a.texel_bary.reshape(-1, 3)[a.mask.ravel()].astype(np.float64)
        want = sum(bary[:, k, None] * X[F[tri, k]] for k in range(3))
        np.testing.assert_allclose(a.interpolate(X), want, rtol=1e-12, atol=1e-12)
    with pytest.raises(ShapeError):
        a.interpolate(np.zeros((len(UV) + 1, 3)))


def test_atlas_partial_coverage_and_overlap_rule():
    V, F, UV = grid(2, uv_box=(0.0, 0.0, 0.5, 0.5))  # only the lower-left quarter of the atlas
    a = UVAtlas(F, UV, 33)
    assert a.mask[16:, :17].all() and not a.mask[:16].any() and not a.mask[:, 17:].any()
    # two triangles on top of each other in UV: the lower index wins
    F2 = np.array([[0, 1, 2], [0, 1, 2]])
    uv2 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    a2 = UVAtlas(F2, uv2, 9)
    assert set(np.unique(a2.texel_tri[a2.mask])) == {0}
    # zero-area UV triangle is skipped
    a3 = UVAtlas(np.array([[0, 1, 2]]), np.array([[0.1, 0.1], [0.5, 0.5], [0.9, 0.9]]), 9)
    assert not a3.mask.any()
    assert uv_atlas(F, UV, 33) is uv_atlas(F.copy(), UV.copy(), 33)  # cached by content


# --------------------------------------------------------------------------------------------
# weights and per-vertex lifting
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("yaw", [0.0, 30.0, 60.0])
def test_obliqueness_weight_is_cosine_power(yaw):
    V, F, _ = grid(4)
    cam = WeakPerspective(50.0, rotation_from_euler(yaw, 0, 0), np.array([100.0, 100.0]))
    n = np.tile([0.0, 0.0, 1.0], (V.shape[0], 1))
    w = obliqueness_weight(n, V, cam, power=2.0)
    np.testing.assert_allclose(w, np.cos(np.deg2rad(yaw)) ** 2, atol=1e-12)
    assert np.all(obliqueness_weight(-n, V, cam) == 0)  # back-facing


def test_lift_vertex_colors_samples_linear_ramp_exactly():
    """Bilinear sampling of a linear colour ramp is exact at any sub-pixel position."""
    H, W = 120, 160
    yy, xx = np.mgrid[:H, :W]
    frame = np.stack([xx, yy, 50 + 0 * xx], -1).astype(np.uint8)
    V, F, _ = grid(6)
    cam = WeakPerspective(37.3, rotation_from_euler(20, 10, 0), np.array([80.3, 61.7]))
    lifted = lift_vertex_colors(frame, V, F, cam, power=1.0)
    p = cam.project(V)
    assert (lifted.weights > 0).all()
    np.testing.assert_allclose(lifted.colors[:, 0], p[:, 0], atol=1e-3)
    np.testing.assert_allclose(lifted.colors[:, 1], p[:, 1], atol=1e-3)
    # plane normal (0, 0, 1) rotated: weight = cos(yaw) cos(pitch)
    R = rotation_from_euler(20, 10, 0)
    np.testing.assert_allclose(lifted.weights, R[2, 2], atol=1e-6)


def test_lift_vertex_colors_occlusion_and_outside():
    """A small front plate hides part of a back plate: those vertices get weight 0."""
    Vb, Fb, _ = grid(8, z=0.0)
    Vf, Ff, _ = grid(2, z=1.0, x0=-0.4, x1=0.4)
    V = np.vstack([Vb, Vf])
    F = np.vstack([Fb, Ff + len(Vb)])
    cam = WeakPerspective(80.0, np.eye(3), np.array([99.5, 99.5]))
    frame = np.full((200, 200, 3), 77, np.uint8)
    lifted = lift_vertex_colors(frame, V, F, cam)
    back = lifted.weights[: len(Vb)]
    hidden = (np.abs(Vb[:, 0]) < 0.4 - 1e-9) & (np.abs(Vb[:, 1]) < 0.4 - 1e-9)
    assert hidden.sum() == 9
    assert np.all(back[hidden] == 0) and np.all(back[~hidden] == 1)
    assert np.all(lifted.weights[len(Vb):] == 1)
    np.testing.assert_allclose(lifted.colors[lifted.weights > 0], 77)
    # camera shifted so the mesh is off the frame: all weights 0, no crash
    far = WeakPerspective(80.0, np.eye(3), np.array([900.0, 900.0]))
    assert np.all(lift_vertex_colors(frame, V, F, far).weights == 0)


# --------------------------------------------------------------------------------------------
# UV lifting, merging, round trip
# --------------------------------------------------------------------------------------------

def test_lift_uv_texture_recovers_known_texture_on_sphere():
    V, F, UV = uv_sphere(32, 64)
    T = 128
    tex = smooth_texture(T)
    size = (320, 320)
    cam = look_at_weak_perspective(V, size, rotation=rotation_from_euler(25, -10, 0), fill=0.9)
    r = render(V, F, cam, size, uvs=UV, texture=tex, shading="none")
    lifted = lift_uv_texture(r.image, V, F, UV, cam, T, raster=r.raster)
    w = lifted.weight
    assert w.shape == (T, T) and lifted.texture.shape == (T, T, 3)
    assert w.max() <= 1 and w.min() >= 0
    good = w > 0.5
    assert good.mean() > 0.1
    # measured mean error about 1.5 grey levels (resampling through a 320 px rendering)
    assert np.abs(lifted.texture[good] - tex[good]).mean() < 3.0
    # texels on the far side of the sphere are not seen
    a = uv_atlas(F, UV, T)
    P = a.interpolate(V)
    facing_away = a.scatter(cam.depth(P)) < -0.2
    assert np.all(w[facing_away & a.mask] == 0)


def test_merge_over_poses_and_rerender_psnr():
    V, F, UV = uv_sphere(32, 64)
    T = 128
    tex = smooth_texture(T, seed=2)
    size = (256, 256)
    lifted = []
    for yaw in (-60, 0, 60, 120, 180, 240):
        cam = look_at_weak_perspective(V, size, rotation=rotation_from_euler(yaw, 15, 0))
        r = render(V, F, cam, size, uvs=UV, texture=tex, shading="none")
        lifted.append(lift_uv_texture(r.image, V, F, UV, cam, T, raster=r.raster))
    merged = merge_textures(lifted)
    assert np.all(np.isfinite(merged.texture))
    # a held-out pose re-rendered with the merged texture
    cam = look_at_weak_perspective(V, size, rotation=rotation_from_euler(30, -20, 0))
    ref = render(V, F, cam, size, uvs=UV, texture=tex, shading="none")
    out = render(V, F, cam, size, uvs=UV, texture=texture_to_uint8(merged.texture), shading="none")
    m = ref.raster.mask
    assert psnr(out.image[m], ref.image[m]) > 30.0  # measured about 35 dB


def test_merge_textures_weighted_mean_exact():
    a = np.full((4, 4, 3), 10.0, np.float32)
    b = np.full((4, 4, 3), 40.0, np.float32)
    wa = np.full((4, 4), 3.0, np.float32)
    wb = np.full((4, 4), 1.0, np.float32)
    wa[0, 0] = wb[0, 0] = 0  # never seen: filled
    m = merge_textures([(a, wa), (b, wb)])
    np.testing.assert_allclose(m.texture[1:, :], 17.5)
    np.testing.assert_allclose(m.texture[0, 0], 17.5, atol=1e-4)  # push-pull from neighbours
    assert m.weight[0, 0] == 0 and m.weight[1, 1] == 4
    # per-vertex colours: no fill by default
    mv = merge_textures([(a[0], wa[0]), (b[0], wb[0])])
    assert mv.texture.shape == (4, 3) and np.all(mv.texture[0] == 0)
    with pytest.raises(TextureError, match=r"fill='pushpull' needs \(T, T, 3\) textures, got \(4, 3\)"):
        merge_textures([(a[0], wa[0])], fill="pushpull")


@pytest.mark.parametrize("method", ["pushpull", "inpaint"])
def test_fill_holes_keeps_known_and_interpolates(method):
    yy, xx = np.mgrid[:64, :64]
    tex = np.stack([xx * 3.0, yy * 3.0, 100 + 0 * xx], -1).astype(np.float32)
    known = np.ones((64, 64), bool)
    known[20:30, 30:40] = False
    out = fill_holes(np.where(known[..., None], tex, 0), known, method=method)
    np.testing.assert_array_equal(out[known], tex[known])
    # smooth fill of a ramp: measured mean error 0.67 (pushpull) and 2.6 (inpaint) on values
    # 60..117 (the known texels' mean would be 10.6 off)
    limit = {"pushpull": 2.0, "inpaint": 5.0}[method]
    assert np.abs(out[~known] - tex[~known]).mean() < limit


def test_fill_vertex_colors_harmonic_reproduces_linear():
    V, F, _ = grid(8)
    C = np.stack([100 + 50 * V[:, 0], 100 + 30 * V[:, 1], 100 + 0 * V[:, 0]], -1)
    known = (np.abs(V[:, 0]) > 0.99) | (np.abs(V[:, 1]) > 0.99)  # boundary only
    out = fill_vertex_colors(np.where(known[:, None], C, 0), known, F)
    np.testing.assert_allclose(out, C, atol=1e-4)


# --------------------------------------------------------------------------------------------
# performance-driven texture function
# --------------------------------------------------------------------------------------------

def _synthetic_frames(n=30, r=3, shape=(16, 16), seed=0):
    """Textures that depend linearly on attributes: tex(a) = base + basis @ a."""
    rng = np.random.default_rng(seed)
    A = rng.uniform(-1, 1, (n, r))
    base = rng.uniform(80, 160, shape + (3,))
    basis = rng.normal(0, 10, shape + (3, r))
    tex = base + np.einsum("...cr,nr->n...c", basis, A)
    return A, tex, base, basis


def test_texture_function_exact_at_training_frames():
    A, tex, *_ = _synthetic_frames()
    w = np.ones(tex.shape[:-1])
    for kernel in ("gaussian", "inverse"):
        tf = TextureFunction(tex, w, A, k=4, kernel=kernel)
        for i in (0, 7, 29):
            np.testing.assert_allclose(tf(A[i]), tex[i], atol=1e-3)


def test_texture_function_interpolates_between_neighbours():
    A, tex, base, basis = _synthetic_frames(n=200, r=2, seed=1)
    tf = TextureFunction(tex, np.ones(tex.shape[:-1]), A, k=6)
    rng = np.random.default_rng(5)
    errs, nn_errs = [], []
    for q in rng.uniform(-0.8, 0.8, (10, 2)):
        truth = base + basis @ q
        errs.append(np.abs(tf(q) - truth).mean())
        nn_errs.append(np.abs(tex[np.argmin(np.linalg.norm(A - q, axis=1))] - truth).mean())
    # kernel-weighted neighbours beat the single nearest frame
    assert np.mean(errs) < np.mean(nn_errs)
    assert np.mean(errs) < 3.0


def test_texture_function_respects_per_texel_visibility():
    A = np.array([[0.0], [1.0], [5.0]])
    tex = np.stack([np.full((2, 2, 3), v, np.float32) for v in (10.0, 50.0, 200.0)])
    w = np.ones((3, 2, 2), np.float32)
    w[0, 0, 0] = 0.0   # frame 0 did not see texel (0, 0)
    w[:, 1, 1] = 0.0   # no frame saw texel (1, 1): fallback to the merged texture
    tf = TextureFunction(tex, w, A, k=2, kernel="inverse")
    out = tf(np.array([0.0]))  # exact match of frame 0
    np.testing.assert_allclose(out[0, 1], 10.0, atol=1e-3)
    np.testing.assert_allclose(out[0, 0], 50.0, atol=1e-3)  # only frame 1 among the 2 nearest
    # the merged texture fills it from the texels seen: (0, 1) and (1, 0) merge all three
    # frames (260 / 3), (0, 0) frames 1 and 2 (125); their mean 99.44 (measured 99.444)
    np.testing.assert_allclose(out[1, 1], (2 * 260 / 3 + 125) / 3, atol=1e-3)
    idx, kappa = tf.neighbours(np.array([0.25]))
    assert list(idx) == [0, 1] and np.isclose(kappa.sum(), 1) and kappa[0] > kappa[1]
    np.testing.assert_allclose(kappa, np.array([1 / 0.25**2, 1 / 0.75**2]) / (16 + 1 / 0.5625))


def test_texture_function_save_load_roundtrip(tmp_path):
    A, tex, *_ = _synthetic_frames(n=8)
    tf = TextureFunction(tex, np.ones(tex.shape[:-1]), A, k=3)
    p = tmp_path / "tf.npz"
    tf.save(p)
    tf2 = TextureFunction.load(p)
    q = np.array([0.1, -0.2, 0.3])
    np.testing.assert_array_equal(tf(q), tf2(q))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(TextureError):
        TextureFunction.load(tmp_path / "bad.npz")


# --------------------------------------------------------------------------------------------
# default texture
# --------------------------------------------------------------------------------------------

def test_default_face_texture_plain_uvs():
    V, F, UV = grid(4)
    t = default_face_texture(UV, size=64, seed=1)
    assert t.shape == (64, 64, 3) and t.dtype == np.uint8
    np.testing.assert_array_equal(t, default_face_texture(UV, size=64, seed=1))
    assert not np.array_equal(t, default_face_texture(UV, size=64, seed=2))
    # skin tone: red > green > blue on average; fine gradients for a KLT tracker
    mean = t.reshape(-1, 3).mean(0)
    assert mean[0] > mean[1] > mean[2]
    gy, gx = np.gradient(t[..., 1].astype(float))
    assert np.median(np.hypot(gx, gy)) > 1.0


def test_default_face_texture_with_ict_landmarks(data_dir):
    from facetransfer.io.mesh import read_obj

    root = data_dir / "ict-facekit" / "FaceXModel"
    mesh = read_obj(root / "generic_neutral_mesh.obj")
    lm = np.asarray(json.loads((root / "vertex_indices.json").read_text())["idx_to_landmark_verts"])

    class _Model:
        uvs = mesh.uvs
        landmarks = lm

    T = 256
    t = default_face_texture(_Model(), size=T).astype(float)
    px = lambda i: tuple(np.rint(mesh.uvs[lm[i]] * [T - 1, -(T - 1)] + [0, T - 1]).astype(int))
    lip = np.mean([t[px(i)[1], px(i)[0]] for i in (51, 57)], axis=0)   # upper/lower lip middles
    cheek = t[px(2)[1], px(2)[0]]                                        # jaw line, left
    assert lip[1] < cheek[1] - 30  # lips less green (redder, darker) than the skin


def test_bad_inputs():
    V, F, UV = grid(2)
    cam = WeakPerspective(10.0, np.eye(3), np.array([20.0, 20.0]))
    frame = np.zeros((40, 40, 3), np.uint8)
    with pytest.raises(ShapeError, match=r"frame must be an \(H, W, 3\) uint8 RGB image, got \(40, 40\) uint8"):
        lift_vertex_colors(frame[..., 0], V, F, cam)
    with pytest.raises(ShapeError, match=r"frame must be an \(H, W, 3\) uint8 RGB image, got \(40, 40, 3\) float64"):
        lift_vertex_colors(frame.astype(float), V, F, cam)
    with pytest.raises(ShapeError, match=r"vertices must be \(n, 3\).*got \(9, 2\)"):
        lift_vertex_colors(frame, V[:, :2], F, cam)
    with pytest.raises(TextureError, match=r"faces index vertices 100\.\.108 but there are 9"):
        lift_vertex_colors(frame, V, F + 100, cam)
    with pytest.raises(TextureError, match=r"no texture coordinates \(uvs is None\)"):
        lift_uv_texture(frame, V, F, None, cam, 16)
    with pytest.raises(ShapeError, match=r"uvs must be \(n_vertices, 2\) = \(9, 2\), got \(3, 2\)"):
        lift_uv_texture(frame, V, F, UV[:3], cam, 16)
    with pytest.raises(TextureError, match=r"atlas was built for other faces, uvs or tex_size"):
        lift_uv_texture(frame, V, F, UV, cam, 16, atlas=UVAtlas(F, UV, 32))
    with pytest.raises(TextureError, match=r"tex_size must be an integer in 2\.\.16384, got 1"):
        UVAtlas(F, UV, 1)
    with pytest.raises(TextureError, match=r"power must be a finite number >= 0, got -1"):
        obliqueness_weight(V, V, cam, power=-1)
    with pytest.raises(TextureError, match=r"need at least one lifted texture"):
        merge_textures([])
    with pytest.raises(ShapeError, match=r"lifted\[1\] has shape \(5, 5, 3\), expected \(4, 4, 3\) like lifted\[0\]"):
        merge_textures([(np.zeros((4, 4, 3)), np.zeros((4, 4))), (np.zeros((5, 5, 3)), np.zeros((5, 5)))])
    with pytest.raises(TextureError, match=r"lifted\[0\] weights must be finite and >= 0"):
        merge_textures([(np.zeros((4, 4, 3)), -np.ones((4, 4)))])
    with pytest.raises(ShapeError, match=r"F = 2 expected, got \(3, 4, 3\) and \(3, 4\)"):
        TextureFunction(np.zeros((3, 4, 3)), np.ones((3, 4)), np.zeros((2, 2)))
    with pytest.raises(TextureError, match=r"k must be an integer >= 1, got 0"):
        TextureFunction(np.zeros((3, 4, 3)), np.ones((3, 4)), np.zeros((3, 2)), k=0)
    tf = TextureFunction(np.zeros((3, 4, 3)), np.ones((3, 4)), np.eye(3))
    with pytest.raises(ShapeError, match=r"attributes must be a finite \(3,\) vector, got shape \(2,\)"):
        tf(np.zeros(2))
    with pytest.raises(TextureError, match=r"size must be an integer in 8\.\.8192, got 4"):
        default_face_texture(np.zeros((5, 2)), size=4)
    with pytest.raises(TextureError, match=r"needs texture coordinates; the model has none"):
        default_face_texture(object())
    with pytest.raises(ValueError, match=r"known \(H, W\) bool expected, got \(4, 4, 3\) and \(4, 4\) float64"):
        fill_holes(np.zeros((4, 4, 3)), np.ones((4, 4)), method="pushpull")


def test_bake_texture_onto_itself_and_remeshed_copy():
    """Baking a mesh's texture onto the same surface (finer tessellation) reproduces it."""
    V, F, UV = uv_sphere(16, 32)
    tex = smooth_texture(128, seed=4)
    V2, F2, UV2 = uv_sphere(32, 64)   # same surface and parameterisation, other mesh
    baked = bake_texture(V2, F2, UV2, V, F, UV, tex, 128, source_samples=256)
    a = uv_atlas(F2, UV2, 128)
    inner = a.mask.copy()
    inner[:12] = inner[-12:] = False  # poles: the coarse sphere's facets are far from the fine one
    assert np.all(baked.distance[inner] < 0.05)
    assert psnr(baked.texture[inner], tex[inner]) > 28.0
    assert baked.texture.dtype == np.uint8 and np.isinf(baked.distance[~a.mask]).all()
    with pytest.raises(TextureError):
        bake_texture(V2, F2, UV2, V, F, UV, tex.astype(float), 64)


def test_lee_perry_smith_texture_onto_its_own_mesh(data_dir, tmp_path, monkeypatch):
    """The scan baked onto itself reproduces its colour map (credit: Lee Perry-Smith, CC-BY 3.0)."""
    from facetransfer.texture import LEE_PERRY_SMITH_CREDIT, lee_perry_smith_texture, load_lee_perry_smith

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("FACETRANSFER_DATA_DIR", str(data_dir))
    mesh, image = load_lee_perry_smith()
    assert image.shape == (1024, 1024, 3) and mesh.vertices.shape == (9279, 3)
    assert "CC-BY 3.0" in LEE_PERRY_SMITH_CREDIT
    T = 256
    tex = lee_perry_smith_texture(mesh.vertices, mesh.faces, mesh.uvs, T, source_samples=512)
    ref = cv2.resize(image, (T, T), interpolation=cv2.INTER_AREA)
    a = uv_atlas(mesh.faces, mesh.uvs, T)
    inner = a.mask & ~cv2.dilate((~a.mask).astype(np.uint8), np.ones((5, 5))).astype(bool)
    assert psnr(tex[inner], ref[inner]) > 30.0  # measured 37 dB at source_samples=512
    cached = list((tmp_path / "facetransfer" / "textures").glob("lee-perry-smith-*.png"))
    assert len(cached) == 1
    np.testing.assert_array_equal(
        lee_perry_smith_texture(mesh.vertices, mesh.faces, mesh.uvs, T, source_samples=512), tex)


def test_texture_function_per_vertex_fills_unseen_vertices():
    V, F, _ = grid(4)
    n = V.shape[0]
    A = np.array([[0.0], [1.0]])
    cols = np.stack([np.tile([100.0, 50.0, 20.0], (n, 1))] * 2).astype(np.float32)
    w = np.ones((2, n), np.float32)
    w[:, 12] = 0  # the centre vertex was never seen
    tf = TextureFunction(cols, w, A, k=2, faces=F)
    np.testing.assert_allclose(tf(np.array([0.3]))[12], [100, 50, 20], atol=1e-3)
    tf0 = TextureFunction(cols, w, A, k=2)
    np.testing.assert_allclose(tf0(np.array([0.3]))[12], 0, atol=1e-3)


def test_lee_perry_smith_on_ict_template(data_dir, tmp_path, monkeypatch):
    """Fit the ICT template to the scan, carry its colour map over; lips red, brows dark."""
    from facetransfer.datasets.ict import ict_template

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("FACETRANSFER_DATA_DIR", str(data_dir))
    t = ict_template("face")

    class _Model:
        uvs = t.mesh.uvs
        landmarks = t.landmarks
        vertex_subset = np.arange(len(t.mesh.uvs))

    T = 256
    tex = default_face_texture(_Model(), size=T, source="lee-perry-smith").astype(float)
    assert tex.shape == (T, T, 3)

    def at(i):
        c, r = np.rint(t.mesh.uvs[t.landmarks[i]] * [T - 1, -(T - 1)] + [0, T - 1]).astype(int)
        return tex[r - 1:r + 2, c - 1:c + 2].reshape(-1, 3).mean(0)

    redness = lambda c: (c[0] - c[1]) / c[0]  # noqa: E731
    lips = np.mean([at(i) for i in (51, 62, 66)], axis=0)
    brows = np.mean([at(i) for i in range(17, 27)], axis=0)
    # nose bridge: the jaw sides fall on stubble, as dark as brows, so they make no reference
    skin = np.mean([at(i) for i in (27, 28, 29)], axis=0)
    # measured: redness lips 0.44, skin 0.25; brightness brows 151, skin 182
    assert redness(lips) > redness(skin) + 0.1
    assert brows.mean() < skin.mean() - 20
    cached = sorted(p.name for p in (tmp_path / "facetransfer" / "textures").iterdir())
    assert any(n.endswith("-fit.npy") for n in cached) and any(n.endswith(f"-{T}.png") for n in cached)
    np.testing.assert_array_equal(default_face_texture(_Model(), size=T, source="auto"), tex)
    # not ICT UVs: auto falls back to procedural, an explicit request is an error
    _, _, UV = grid(4)
    np.testing.assert_array_equal(default_face_texture(UV, size=32, source="auto"),
                                  default_face_texture(UV, size=32))
    with pytest.raises(TextureError):
        default_face_texture(UV, size=32, source="lee-perry-smith")
    with pytest.raises(TextureError):
        default_face_texture(UV, size=32, source="photo")
