"""The exported face's teeth (``facetransfer.export.teeth``): a glb's and a USD's open mouth showed
a dark hole where the `view` page and a rewrite show teeth. Now an upper row rigid with the head
and a lower row moved by the jaw shapes, on the dental arches a rewrite draws its teeth on."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.export import export_track

sys.path.insert(0, str(Path(__file__).parent))

from test_export import _read_accessor, _validate  # noqa: E402


@pytest.fixture(scope="module")
def case(arkit_model, make_arkit_track):
    return (arkit_model,) + make_arkit_track(arkit_model)


def _reference_fit(P: np.ndarray, Q: np.ndarray):
    """The least-squares rotation and translation carrying ``P`` to ``Q`` by scipy's
    ``Rotation.align_vectors`` of the centred points (an implementation of its own)."""
    from scipy.spatial.transform import Rotation

    p, q = P.mean(axis=0), Q.mean(axis=0)
    rot, _ = Rotation.align_vectors(Q - q, P - p)
    R = rot.as_matrix()
    return R, q - R @ p


def _rays_hit(points: np.ndarray, V: np.ndarray, F: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: a triangle of ``V[F]`` lies in front of each point along the unit
    direction ``d`` (Möller–Trumbore, every point against every triangle)."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = B - A, C - A
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-12
    A, e1, e2, h, det = A[ok], e1[ok], e2[ok], h[ok], det[ok]
    out = np.zeros(len(points), bool)
    for i, p in enumerate(points):
        s = p - A
        u = np.einsum("ij,ij->i", s, h) / det
        qv = np.cross(s, e1)
        v = (qv @ d) / det
        t = np.einsum("ij,ij->i", e2, qv) / det
        out[i] = bool(np.any((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)))
    return out


def test_glb_has_upper_and_lower_teeth_whose_lower_row_follows_the_jaw(case, tmp_path):
    """The glb's face mesh had its skin and its mouth's inside: a wide jawOpen showed a dark
    hole. Now two more primitives, the upper and the lower teeth, in the palette's teeth colour
    (``COLOR_0``). The upper row is rigid (its 52 morph targets all zeros); the lower row's
    jawOpen, jawLeft, jawRight and jawForward targets are the rigid motion fitted (here by
    scipy's align_vectors) to the chin's vertices in that shape, and no other shape moves it."""
    from pygltflib import GLTF2

    from facetransfer.export.teeth import JAW_SHAPES, chin_vertices
    from facetransfer.dental import dental_arch
    from facetransfer.topology import mesh_topology

    model, track, a, _ = case
    out = export_track(track, "glb", tmp_path / "face.glb", model=model)
    g = GLTF2().load(str(out))
    prims = g.meshes[0].primitives
    assert len(prims) == 5 and g.materials[prims[4].material].name == "eyeSocket"  # then sockets
    upper, lower = prims[2], prims[3]
    assert g.materials[upper.material].name == "teeth" and g.materials[upper.material].doubleSided
    face = _read_accessor(g, prims[0].attributes.POSITION).astype(np.float64)
    deltas = np.stack([_read_accessor(g, t["POSITION"]) for t in prims[0].targets]).astype(
        np.float64)
    for prim in (upper, lower):
        C = _read_accessor(g, prim.attributes.COLOR_0)
        assert len(prim.targets) == 52 and C.min() > 0.0 and C.max() <= 1.0
        assert (C.mean(axis=0)[0] > C.mean(axis=0)[2])          # the palette's warm white
    for t in upper.targets:
        assert not np.any(_read_accessor(g, t["POSITION"]))
    L = _read_accessor(g, lower.attributes.POSITION).astype(np.float64)
    U = _read_accessor(g, upper.attributes.POSITION).astype(np.float64)
    assert L[:, 1].mean() < U[:, 1].mean()                          # below the upper row
    arch = dental_arch(face, mesh_topology(model),
                       np.asarray(model.landmarks)[[36, 39, 42, 45]])
    chin = chin_vertices(model, face, arch)
    assert chin.size > 20
    for name, t in zip(ARKIT_NAMES, lower.targets):
        D = _read_accessor(g, t["POSITION"]).astype(np.float64)
        if name not in JAW_SHAPES:
            assert not np.any(D), name
            continue
        d = deltas[ARKIT_NAMES.index(name)]
        R, tr = _reference_fit(face[chin], face[chin] + d[chin])
        np.testing.assert_allclose(D, L @ R.T + tr - L, atol=2e-7)  # metres, float32
        assert np.abs(D).max() > 1e-4
    jaw = _read_accessor(g, lower.targets[ARKIT_NAMES.index("jawOpen")]["POSITION"])
    assert jaw[:, 1].mean() < -0.005                                  # jawOpen: down, in metres
    issues = _validate(out)  # last: skips when node or the validator is absent
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_the_lower_teeth_turn_by_a_jaws_known_rotation(case):
    """A face whose jawOpen turns every vertex by 17 degrees about a hinge behind the mouth (and
    jawLeft shifts it 0.4 units aside): the lower teeth's targets are that rotation and that
    shift of their points to 1e-9; the upper teeth and every other shape do not move them."""
    from scipy.spatial.transform import Rotation

    from facetransfer.arkit import expression_rig
    from facetransfer.export.teeth import rigid_fit, teeth_of

    model, track, _, _ = case
    V = expression_rig(model, track.weights_at(0)).neutral
    hinge = np.array([0.0, V[:, 1].mean(), V[:, 2].min()])
    R0 = Rotation.from_rotvec([np.radians(17.0), 0.02, -0.01]).as_matrix()
    t0 = hinge - R0 @ hinge
    deltas = np.zeros((52,) + V.shape)
    deltas[ARKIT_NAMES.index("jawOpen")] = V @ R0.T + t0 - V
    deltas[ARKIT_NAMES.index("jawLeft")] = [0.4, 0.0, 0.0]
    deltas[ARKIT_NAMES.index("mouthClose")] = np.random.default_rng(0).normal(0, 0.3, V.shape)
    teeth = teeth_of(model, V, list(deltas))
    R, t = teeth.fits["jawOpen"]
    np.testing.assert_allclose(R, R0, atol=1e-12)
    np.testing.assert_allclose(t, t0, atol=1e-9)
    L = teeth.lower.points
    moves = dict(zip(ARKIT_NAMES, teeth.lower_deltas(ARKIT_NAMES)))
    np.testing.assert_allclose(moves["jawOpen"][0], L @ R0.T + t0 - L, atol=1e-9)
    np.testing.assert_allclose(moves["jawOpen"][1], teeth.lower.normals @ R0.T
                               - teeth.lower.normals, atol=1e-12)
    np.testing.assert_allclose(moves["jawLeft"][0], np.tile([0.4, 0.0, 0.0], (len(L), 1)),
                               atol=1e-12)
    assert not np.any(moves["mouthClose"][0]) and set(teeth.fits) == {"jawOpen", "jawLeft",
                                                                       "jawRight", "jawForward"}
    np.testing.assert_allclose(rigid_fit(L, L @ R0.T + t0)[0], R0, atol=1e-12)


def test_no_tooth_stands_in_front_of_the_lips_and_an_open_jaw_shows_them(case):
    """Rays from points on both rows toward a camera in front: at rest every one meets the face
    before the camera or passes the lips' opening (the inner-lip loop as the camera sees it)
    behind the lips' inner edge, none in front of the lips; at jawOpen 1 more pass it."""
    from facetransfer.arkit import expression_rig
    from facetransfer.export.teeth import teeth_of
    from facetransfer.topology import inside_polygon, mesh_topology

    model, track, _, _ = case
    rig = expression_rig(model, track.weights_at(0))
    teeth = teeth_of(model, rig.neutral, list(rig.deltas))
    F = np.asarray(model.faces, np.int64)
    loop = mesh_topology(model).mouth_loop
    d = np.array([0.0, 0.0, 1.0])
    bary = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]]) / np.array([[3], [6], [6], [6]])
    seen = {}
    for w in ("rest", "jawOpen"):
        V = rig.neutral + (rig.deltas[ARKIT_NAMES.index(w)] if w != "rest" else 0.0)
        pts = []
        for row, moves in ((teeth.upper, None), (teeth.lower, teeth.lower_deltas([w]))):
            P = row.points + (moves[0][0] if moves else 0.0)
            pts.append(np.einsum("sk,tkd->tsd", bary, P[row.tris]).reshape(-1, 3))
        pts = np.concatenate(pts)
        free = ~_rays_hit(pts, V, F, d)
        assert inside_polygon(V[loop, :2], pts[free, :2]).all()
        assert (pts[free, 2] < V[loop, 2].max()).all()
        seen[w] = free.mean()
    assert seen["rest"] < 0.1 and seen["jawOpen"] > seen["rest"] + 0.02


def test_usd_has_the_glbs_teeth_on_the_head_and_the_jaw_shapes(case, tmp_path):
    """The USD had the glb's mouth's inside and no teeth. Now ``/Face/teethUpper`` (rigid: no
    blend shapes) and ``/Face/teethLower`` with a blend shape per jaw shape, weighted by the
    face's SkelAnimation by name, both on the ``head`` joint with vertex ``displayColor``; the
    points and offsets are the glb's (model units, not metres)."""
    pytest.importorskip("pxr", reason="usd-core is not installed (extra [usd])")
    from pxr import Usd, UsdGeom, UsdSkel

    from facetransfer.arkit import expression_rig
    from facetransfer.export.teeth import JAW_SHAPES, teeth_of

    model, track, a, _ = case
    stage = Usd.Stage.Open(str(export_track(track, "usd", tmp_path / "f.usda", model=model)))
    teeth = teeth_of(model, expression_rig(model, track.weights_at(0)).neutral,
                     list(expression_rig(model, track.weights_at(0)).deltas))
    for name, row in (("teethUpper", teeth.upper), ("teethLower", teeth.lower)):
        prim = stage.GetPrimAtPath(f"/Face/{name}")
        assert prim.IsValid()
        mesh = UsdGeom.Mesh(prim)
        np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), row.points, atol=1e-5)
        binding = UsdSkel.BindingAPI(prim)
        assert [str(t) for t in binding.GetSkeletonRel().GetTargets()] == ["/Face/Skel"]
        assert list(binding.GetJointIndicesPrimvar().Get()) == [0]
        colours = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor").Get()
        assert len(colours) == len(row.points)
    upper = UsdSkel.BindingAPI(stage.GetPrimAtPath("/Face/teethUpper"))
    assert not upper.GetBlendShapesAttr().HasAuthoredValue()
    lower = UsdSkel.BindingAPI(stage.GetPrimAtPath("/Face/teethLower"))
    names = list(lower.GetBlendShapesAttr().Get())
    assert sorted(names) == sorted(JAW_SHAPES)
    moves = dict(zip(ARKIT_NAMES, teeth.lower_deltas(ARKIT_NAMES)))
    for name, target in zip(names, lower.GetBlendShapeTargetsRel().GetTargets()):
        offsets = np.array(UsdSkel.BlendShape(stage.GetPrimAtPath(target)).GetOffsetsAttr().Get())
        np.testing.assert_allclose(offsets, moves[name][0], atol=1e-5)
    # UsdSkel's own evaluation: the SkelAnimation's weights of frame 3 taken by name
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face")), Usd.PrimDefaultPredicate)
    prim = stage.GetPrimAtPath("/Face/teethLower")
    anim = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/Face/Skel"))).GetAnimQuery()
    w = cache.GetSkinningQuery(prim).GetBlendShapeMapper().Remap(
        anim.ComputeBlendShapeWeights(Usd.TimeCode(3)))
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
    sub, idx, subidx = query.ComputeSubShapeWeights(w)
    pts = UsdGeom.Mesh(prim).GetPointsAttr().Get()
    query.ComputeDeformedPoints(sub, idx, subidx, query.ComputeBlendShapePointIndices(),
                                query.ComputeSubShapePointOffsets(), pts)
    want = teeth.lower.points + sum(float(a[3, ARKIT_NAMES.index(n)]) * moves[n][0]
                                    for n in JAW_SHAPES)
    np.testing.assert_allclose(np.array(pts), want, atol=1e-4)
    assert np.abs(want - teeth.lower.points).max() > 0.1
