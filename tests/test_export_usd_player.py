"""The exported USD as UsdSkel itself evaluates it, against what the project says the face is.

tests/test_export.py reads the file back and adds the blend-shape offsets itself; here usd-core
computes what a USD consumer shows, its own way: ``UsdSkel.Cache`` finds the skeleton binding
under the SkelRoot, the ``SkelAnimation``'s weights at time t (``AnimQuery``) are remapped to the
mesh's ``skel:blendShapes`` and applied by ``UsdSkel.BlendShapeQuery`` (``ComputeSubShapeWeights``,
``ComputeDeformedPoints``), the joint's skinning transforms (``SkeletonQuery``) skin them
(``SkinningQuery.ComputeSkinnedPoints``: the result is in skeleton space, the skinned prim's own
transform is ignored), the skeleton's world transform (``UsdGeom.XformCache``) places them,
and ``metersPerUnit`` turns stage units into metres. Between time codes USD interpolates linearly:
floats and vectors by lerp, quaternions (``quatf[]`` rotations) by ``GfSlerp``, element by
element (OpenUSD ``pxr/usd/usd/interpolators.cpp``, ``Usd_Lerp`` for ``GfQuatf``).

:func:`_faults` is the check; ``test_usd_rejects_a_broken_exporter`` feeds it files written by
deliberately broken exporters and asserts it names what is wrong with each.
Without usd-core (the optional extra ``facetransfer[usd]``) the module skips.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pxr", reason="usd-core is not installed (the optional extra [usd])")

from pxr import Usd, UsdGeom, UsdSkel, Vt  # noqa: E402

from facetransfer.arkit import ARKIT_NAMES, ExpressionRig  # noqa: E402
from facetransfer.export import export_track  # noqa: E402
from facetransfer.export import usd  # noqa: E402
from facetransfer.export.common import head_translation, require_activations  # noqa: E402
from facetransfer.export.gltf import METRES_PER_UNIT  # noqa: E402

#: Worst vertex error (m) allowed between UsdSkel's face and the project's, keys and half-way;
#: measured 1.0e-7 .. 1.2e-7 (float32 points, offsets and weights in centimetres).
TOLERANCE_M = 3e-7


def _usd_shows(path, times, *, first: int = 0) -> dict:
    """What usd-core computes of the USD file ``path`` at frames ``times`` (time codes ``first +
    times``, fractions between them): per time the world points (metres), the weights in the
    mesh's blend-shape order, the SkelRoot's bound; and the stage's facts (timing, axes, names,
    topology, st)."""
    stage = Usd.Stage.Open(str(path))
    root = UsdSkel.Root(stage.GetDefaultPrim())
    cache = UsdSkel.Cache()
    cache.Populate(root, Usd.PrimDefaultPredicate)
    (binding,) = cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate)
    skel = cache.GetSkelQuery(binding.GetSkeleton())
    (skin,) = [s for s in binding.GetSkinningTargets()        # the face's, not the eyes'
               if s.GetPrim().GetPath() == "/Face/Mesh"]         # or the mouth's inside
    shapes = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(skin.GetPrim()))
    indices, offsets = shapes.ComputeBlendShapePointIndices(), shapes.ComputeSubShapePointOffsets()
    mesh, mapper = UsdGeom.Mesh(skin.GetPrim()), skin.GetBlendShapeMapper()
    mpu, xforms = UsdGeom.GetStageMetersPerUnit(stage), UsdGeom.XformCache()
    frames = []
    for tc in times:
        t = Usd.TimeCode(first + tc)
        xforms.SetTime(t)
        w = skel.GetAnimQuery().ComputeBlendShapeWeights(t)  # the animation's order
        if mapper is not None and not mapper.IsNull():
            w = mapper.Remap(w)  # -> the mesh's skel:blendShapes order
        sub, shape_of, sub_of = shapes.ComputeSubShapeWeights(w)
        points = mesh.GetPointsAttr().Get(t)
        assert shapes.ComputeDeformedPoints(sub, shape_of, sub_of, indices, offsets, points)
        shaped = Vt.Vec3fArray(points)
        skinning = skel.ComputeSkinningTransforms(t)
        assert skin.ComputeSkinnedPoints(skinning, points, t)
        S = np.array(xforms.GetLocalToWorldTransform(skel.GetPrim()))  # row vectors: p S
        rigid = np.array(skin.ComputeSkinnedTransform(skinning, t)) @ S
        bound = UsdGeom.BBoxCache(t, [UsdGeom.Tokens.default_]).ComputeWorldBound(
            root.GetPrim()).ComputeAlignedRange()
        frames.append({
            "weights": np.array(w, np.float64),
            "world": (np.array(points, np.float64) @ S[:3, :3] + S[3, :3]) * mpu,
            "rigid": (np.array(shaped, np.float64) @ rigid[:3, :3] + rigid[3, :3]) * mpu,
            "bound": np.array([bound.GetMin(), bound.GetMax()], np.float64) * mpu})
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    return {
        "frames": frames, "metres_per_unit": mpu, "up": UsdGeom.GetStageUpAxis(stage),
        "tcps": stage.GetTimeCodesPerSecond(), "fps": stage.GetFramesPerSecond(),
        "range": (stage.GetStartTimeCode(), stage.GetEndTimeCode()),
        "anim_shapes": list(skel.GetAnimQuery().GetBlendShapeOrder()),
        "mesh_shapes": list(skin.GetBlendShapeOrder()),
        "targets": [p.name for p in skin.GetBlendShapeTargetsRel().GetTargets()],
        "rest": np.array(mesh.GetPointsAttr().Get(), np.float64) * mpu,
        "faces": np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3),
        "counts": np.array(mesh.GetFaceVertexCountsAttr().Get()),
        "orientation": mesh.GetOrientationAttr().Get(),
        "st": None if not primvar else (np.array(primvar.Get(), np.float64),
                                        primvar.GetInterpolation())}


def _face(model, weights, rotation, translation_units) -> np.ndarray:
    """The face as the project says it is: the model's mesh of ``weights`` in metres, turned by
    the head's model-to-camera ``rotation`` and moved by its translation (export/common.py)."""
    V = model.synthesize(weights).reshape(-1, 3) * METRES_PER_UNIT
    return V @ np.asarray(rotation).T + np.asarray(translation_units) * METRES_PER_UNIT


def _wanted(model, track, time: float) -> np.ndarray:
    """The project's face at frame ``time`` (a key, or half-way: the weights and translation
    lerped, the rotation slerped, as USD interpolates)."""
    from scipy.spatial.transform import Rotation, Slerp

    T, k, f = head_translation(track), int(np.floor(time)), time - np.floor(time)
    if f == 0:
        return _face(model, track.weights_at(k), track.rotation[k], T[k])
    w = {n: (1 - f) * track.weights[n][k] + f * track.weights[n][k + 1] for n in track.mode_names}
    R = Slerp([0.0, 1.0], Rotation.from_matrix(track.rotation[k:k + 2]))(f).as_matrix()
    return _face(model, w, R, (1 - f) * T[k] + f * T[k + 1])


def _outward(shown, model) -> float:
    """The share of the triangles at the chin, brows and nose (landmarks 6-10, 17-35: the face's
    front, which looks along +Z) whose front faces +Z: USD's front is counter-clockwise seen
    from outside for a ``rightHanded`` mesh, clockwise for ``leftHanded`` (UsdGeomMesh,
    orientation). Around the eyes and lips some triangles face into the head."""
    V, F = shown["rest"], shown["faces"]
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n *= 1.0 if shown["orientation"] == UsdGeom.Tokens.rightHanded else -1.0
    L = np.asarray(model.landmarks)
    front = np.isin(F, np.r_[L[6:11], L[17:36]]).any(axis=1)
    return float(np.mean(n[front, 2] > 0))


def _faults(shown, model, track, times, *, first: int = 0) -> dict:
    """What is wrong with the USD file ``shown`` (:func:`_usd_shows` at frames ``times``, time
    codes from ``first``) as the export of ``track``: check name -> what was seen; empty when the
    file is right."""
    bad, F = {}, track.n_frames
    if (shown["tcps"], shown["fps"], shown["range"]) != (track.fps, track.fps,
                                                          (first, first + F - 1)):
        bad["time"] = (shown["tcps"], shown["fps"], shown["range"])
    if not shown["anim_shapes"] == shown["mesh_shapes"] == shown["targets"] == list(ARKIT_NAMES):
        bad["names"] = "blend shapes not the ARKit names in order"
    a = require_activations(track).astype(np.float64)
    err = {}
    for time, fr in zip(times, shown["frames"]):
        if time == int(time):
            w = np.abs(fr["weights"] - a[int(time)]).max()
            if w > 1e-7:
                bad.setdefault("weights", {})[time] = w
        want = _wanted(model, track, time)
        err[time] = float(np.abs(fr["world"] - want).max())
        if np.abs(fr["rigid"] - fr["world"]).max() > TOLERANCE_M:  # two USD paths agree
            bad["rigid"] = time
        # the SkelRoot's bound at a key is the posed face's box (USD lerps it between keys)
        box = np.array([fr["world"].min(axis=0), fr["world"].max(axis=0)])
        if time == int(time) and np.abs(fr["bound"] - box).max() > 1e-6:
            bad.setdefault("extent", {})[time] = fr["bound"] - box
    if max(err.values()) > TOLERANCE_M:
        bad["points"] = err
    # the rest face in USD's frame: +Y up, the subject's left at +X, the nose toward +Z, metres
    L = shown["rest"][np.asarray(model.landmarks)]  # the 68-point scheme
    eyes = L[42:48].mean(axis=0) - L[36:42].mean(axis=0)  # the subject's left eye - right
    if not (shown["up"] == UsdGeom.Tokens.y and 0.04 < eyes[0] < 0.09
            and 0.08 < L[17:27].mean(axis=0)[1] - L[8][1] < 0.2
            and L[30][2] > (L[36:48].mean(axis=0))[2] + 0.01):
        bad["axes"] = (shown["up"], eyes, L[30])
    if not (np.all(shown["counts"] == 3) and _outward(shown, model) > 0.95):
        bad["winding"] = _outward(shown, model)
    # st as UsdPreviewSurface reads it, (0, 0) the image's bottom left: the project's uvs (row 0
    # of a texture is v = 1, render.sample_texture), per vertex
    st = shown["st"]
    if st is None or st[1] != UsdGeom.Tokens.vertex or not np.allclose(st[0], model.uvs,
                                                                       atol=1e-6):
        bad["st"] = "st is not the model's uvs per vertex"
    return bad


KEYS = (0, 2, 5)
HALF = (3.5, 3.25)  # between keys 3 and 4: half-way, and where a slerp and an nlerp differ


@pytest.fixture(scope="module")
def case(arkit_model, make_arkit_track, tmp_path_factory):
    track, a, _ = make_arkit_track(arkit_model, 6)
    out = export_track(track, "usd", tmp_path_factory.mktemp("usdskel") / "face.usdc",
                       model=arkit_model)
    return arkit_model, track, out


def test_usdskel_shows_the_tracked_face(case):
    model, track, out = case
    times = KEYS + HALF
    shown = _usd_shows(out, times)
    err = {t: float(np.abs(fr["world"] - _wanted(model, track, t)).max())
           for t, fr in zip(times, shown["frames"])}
    print("UsdSkel vs the project, max vertex error (m) at time code:", err)
    print("front triangles facing +Z:", _outward(shown, model))
    assert _faults(shown, model, track, times) == {}
    assert shown["metres_per_unit"] == 0.01 and shown["up"] == "Y"
    # the frames differ by far more than the tolerance (the comparison can fail)
    apart = np.abs(_wanted(model, track, 3) - _wanted(model, track, 4)).max()
    assert apart > 1000 * TOLERANCE_M
    # the head where the image shows it: right of the frame's centre is +X, above it is +Y
    centre = shown["frames"][0]["world"][np.asarray(model.landmarks)].mean(axis=0)
    (tx, ty), (W, H) = track.translation[0], track.frame_size
    assert np.sign(centre[0]) == np.sign(tx - W / 2) and np.sign(centre[1]) == np.sign(H / 2 - ty)


def test_usd_passes_usds_validators(case):
    """usd-core's own validators (``UsdValidation``, usd-core >= 24.11: stage metadata, skel
    binding, encapsulation, ...) find nothing; ``UsdUtils.ComplianceChecker`` (usdchecker's
    older engine) is run too where this usd-core still has it."""
    _, _, out = case
    stage = Usd.Stage.Open(str(out))
    try:
        from pxr import UsdValidation
    except ImportError:
        UsdValidation = None
    if UsdValidation is not None:
        reg = UsdValidation.ValidationRegistry()
        errors = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators()).Validate(stage)
        assert not errors, [(e.GetName(), e.GetMessage()) for e in errors]
    try:
        from pxr.UsdUtils.complianceChecker import ComplianceChecker
    except ImportError:
        ComplianceChecker = None
    if ComplianceChecker is not None:
        checker = ComplianceChecker()
        checker.CheckCompliance(str(out))
        assert not checker.GetErrors() and not checker.GetFailedChecks(), checker.GetErrors()
    if UsdValidation is None and ComplianceChecker is None:
        pytest.skip("this usd-core has neither UsdValidation nor ComplianceChecker")


def test_usd_of_a_plate_lies_on_its_frames(case, tmp_path):
    """A track of an image sequence numbered from 1001 (a VFX plate): frame k at time code
    1001 + k, the same face there."""
    import dataclasses

    import cv2

    model, track, _ = case
    for n in (1001, 1002, 1003):
        cv2.imwrite(str(tmp_path / f"f.{n:04d}.png"), np.full((8, 8, 3), 90, np.uint8))
    # the plate's numbering recorded as tracking records it (its 8x8 frames are not the
    # track's size: read at export, as an older track's, they would be taken for another clip)
    on_plate = dataclasses.replace(track, source=str(tmp_path / "f.%04d.png")).with_source_facts()
    assert on_plate.source_facts.first_frame == 1001
    out = export_track(on_plate, "usd", tmp_path / "plate.usd", model=model)
    times = (0, 4, 4.5)
    shown = _usd_shows(out, times, first=1001)
    assert _faults(shown, model, track, times, first=1001) == {}
    assert "time" in _faults(shown, model, track, times)  # from 0 it is not


# ------------------------------------------------------------------------------ broken exporters
def _edited(edit):
    """An exporter that writes the real file, then ``edit(stage)`` spoils it."""
    def write(track, model, out, monkeypatch):
        usd.write_usd(track, model, out)
        stage = Usd.Stage.Open(str(out))
        edit(stage)
        stage.Save()
    return write


def _patched(name, replacement, **kw):
    """The real exporter with ``usd.<name>`` replaced by ``replacement(original)``."""
    def write(track, model, out, monkeypatch):
        monkeypatch.setattr(usd, name, replacement(getattr(usd, name)))
        usd.write_usd(track, model, out, **kw)
    return write


def _rig(change):
    return _patched("identity_rig", lambda f: lambda t, m: ExpressionRig(*change(f(t, m))))


def _anim_shapes(stage):
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Face/Skel/Anim"))
    names = list(ARKIT_NAMES)
    j, k = names.index("jawOpen"), names.index("eyeBlinkLeft")
    names[j], names[k] = names[k], names[j]
    anim.GetBlendShapesAttr().Set(names)


def _targets_rotated(stage):
    rel = UsdSkel.BindingAPI(stage.GetPrimAtPath("/Face/Mesh")).GetBlendShapeTargetsRel()
    t = list(rel.GetTargets())
    rel.SetTargets(t[1:] + t[:1])


def _winding(stage):
    attr = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh")).GetFaceVertexIndicesAttr()
    attr.Set(Vt.IntArray.FromNumpy(np.array(attr.Get()).reshape(-1, 3)[:, ::-1].ravel()))


def _st_flipped(stage):
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Face/Mesh")).GetPrimvar("st")
    st = np.array(pv.Get())
    pv.Set(Vt.Vec2fArray.FromNumpy(np.stack([st[:, 0], 1 - st[:, 1]], 1).astype(np.float32)))


def _no_extent(stage):
    for path in ("/Face", "/Face/Mesh"):
        stage.GetPrimAtPath(path).GetAttribute("extent").Clear()


BROKEN = {  # name: (exporter, the check that must name it)
    "weights a frame late": (_patched("require_activations", lambda f: lambda t: np.vstack(
        [f(t)[:1], f(t)[:-1]])), "weights"),
    "metersPerUnit 1 (centimetres called metres)": (
        _edited(lambda s: UsdGeom.SetStageMetersPerUnit(s, 1.0)), "points"),
    "the face in metres on a centimetre stage": (
        _rig(lambda r: (r.neutral * 0.01, r.deltas * 0.01)), "points"),
    "translation in metres on a centimetre stage": (
        _patched("head_translation", lambda f: lambda t: f(t) * 0.01), "points"),
    "quaternion as (w, x, y, z) read as (x, y, z, w)": (
        _patched("head_quaternions", lambda f: lambda R: f(R)[:, [3, 0, 1, 2]]), "points"),
    "the inverse rotation": (
        _patched("head_quaternions", lambda f: lambda R: f(np.swapaxes(R, 1, 2))), "points"),
    "time codes off by one": (lambda t, m, out, mp: usd.write_usd(t, m, out, first_frame=1),
                              "time"),
    "timeCodesPerSecond 30 for a 25 fps track": (
        _edited(lambda s: s.SetTimeCodesPerSecond(30)), "time"),
    "blend-shape names swapped in the animation": (_edited(_anim_shapes), "names"),
    "blend-shape targets permuted": (_edited(_targets_rotated), "points"),
    "offsets of the wrong sign": (_rig(lambda r: (r.neutral, -r.deltas)), "points"),
    "the face mirrored (its left on -X)": (
        _rig(lambda r: (r.neutral * [-1, 1, 1], r.deltas * [-1, 1, 1])), "axes"),
    "Z up": (_edited(lambda s: UsdGeom.SetStageUpAxis(s, UsdGeom.Tokens.z)), "axes"),
    "winding reversed": (_edited(_winding), "winding"),
    "leftHanded orientation": (_edited(lambda s: UsdGeom.Mesh(s.GetPrimAtPath(
        "/Face/Mesh")).GetOrientationAttr().Set(UsdGeom.Tokens.leftHanded)), "winding"),
    "st with v flipped": (_edited(_st_flipped), "st"),
    "no extents (the exporter before s44)": (_edited(_no_extent), "extent"),
}


@pytest.mark.parametrize("name", list(BROKEN))
def test_usd_rejects_a_broken_exporter(case, name, tmp_path, monkeypatch):
    model, track, _ = case
    write, check = BROKEN[name]
    out = tmp_path / "broken.usdc"
    write(track, model, out, monkeypatch)
    times = KEYS + HALF
    faults = _faults(_usd_shows(out, times), model, track, times)
    assert check in faults, (name, faults)

