"""USD with UsdSkel blend shapes: the clip's person, 52 ARKit ``BlendShape`` prims, a SkelAnimation.

Layout (``usd-core``, the optional extra ``facetransfer[usd]``)::

    /Face                 SkelRoot (default prim); stage Y up, metersPerUnit 0.01 (model units);
                          extent per time code: the posed face's box (:func:`posed_extents`)
      /Face/Skel          Skeleton, joints "head", "head/eyeRight", "head/eyeLeft" (the eyes'
                          centres); skel:animationSource -> Anim
        /Face/Skel/Anim   SkelAnimation: blendShapes (52 ARKit names), blendShapeWeights,
                          translations / rotations / scales of the joints: one time sample per
                          frame (the eyes turned by the gaze, :mod:`.gltf_eyes`; an eye
                          joint's scale SHUT_SCALE while its lids are shut,
                          :func:`.gltf_eyes.eyes_shown`, else 1)
      /Face/Mesh          Mesh (neutral face and its extent, primvars:st), SkelBindingAPI:
                          skel:skeleton, skel:blendShapes + skel:blendShapeTargets, every
                          vertex on "head"
        /Face/Mesh/<name> BlendShape: offsets f_j - f_0 (pointIndices when sparse)
      /Face/eyeSockets    Mesh, the eye sockets (:func:`.gltf_eyes.socket_cones`) on "head",
                          with its own 52 BlendShape prims (the lids' deltas; none without eyes)
      /Face/eyeRight      Mesh, the eyeball (displayColor), every vertex on "head/eyeRight"
      /Face/eyeLeft       likewise on "head/eyeLeft" (no eyes for a model without landmarks)
      /Face/mouthInside   Mesh, the mouth's inside (:func:`.gltf.mouth_cone`) on "head", with
                          its own 52 BlendShape prims (the lips' deltas)
      /Face/teethUpper    Mesh, the upper teeth (:mod:`.teeth`, displayColor) on "head", rigid
      /Face/teethLower    Mesh, the lower teeth on "head", with a BlendShape prim per jaw shape
                          (jawOpen, jawLeft, jawRight, jawForward: the jaw's rigid motion)

Time codes are frame numbers (``timeCodesPerSecond`` = the clip's fps): from 0, or, for a
track of an image sequence numbered from N (a VFX plate's 1001), from N, so that the
animation lies on the plate's own frames in a compositor or DCC (:func:`source_first_frame`).

References
----------
Pixar USD, UsdSkel schemas: ``UsdSkelBlendShape``, ``UsdSkelAnimation``,
``UsdSkelBindingAPI`` ("Blend Shapes" and "Binding" in the UsdSkel documentation).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..arkit import ARKIT_NAMES
from ..io.atomic import atomic_path
from .common import ExportError, head_quaternions, head_translation, identity_rig, \
    require_activations, source_name

__all__ = ["write_usd", "source_first_frame", "posed_extents", "USD_SUFFIXES"]

USD_SUFFIXES = (".usd", ".usda", ".usdc")


def _pxr():
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt
    except ImportError:
        raise ExportError("USD export needs usd-core: pip install 'facetransfer[usd]'") from None
    return Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt


def _tri_mesh(stage, path: str, points: np.ndarray, tris: np.ndarray, pxr):
    """A triangle ``UsdGeom.Mesh`` at ``path``: ``points`` (n, 3), ``tris`` (m, 3) or flat, its
    extent the points' box, right-handed, not subdivided."""
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    mesh = UsdGeom.Mesh.Define(stage, path)
    tris = np.asarray(tris, np.int32).reshape(-1, 3)
    pts = Vt.Vec3fArray.FromNumpy(np.asarray(points, np.float32))
    mesh.CreatePointsAttr(pts)
    mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(tris.ravel()))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return mesh


def _mesh(stage, rig, model, pxr):
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    mesh = _tri_mesh(stage, "/Face/Mesh", rig.neutral, model.faces, pxr)   # rest pose's box
    if model.uvs is not None:
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(model.uvs, np.float32)))
    return mesh


def _blend_shapes(stage, mesh, deltas, pxr, names=ARKIT_NAMES):
    """A ``BlendShape`` prim under ``mesh`` per name of ``names`` (the ARKit names), of
    ``deltas`` (one ``(n, 3)`` each)."""
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    paths = []
    for name, d in zip(names, deltas):
        bs = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(name))
        idx = np.flatnonzero(np.any(d != 0, axis=1)).astype(np.int32)
        if idx.size == 0:  # a shape the model lacks (tongueOut): one zero offset
            idx = np.zeros(1, np.int32)
        if idx.size == len(d):  # dense: offsets for every point, no indices
            bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(d.astype(np.float32)))
        else:
            bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(d[idx].astype(np.float32)))
            bs.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(idx))
        paths.append(bs.GetPath())
    return paths


def source_first_frame(track) -> int:
    """The first frame number of the image sequence a track was made from (1001 for a plate
    numbered from 1001), as the track records it, else (an older track) read from its
    ``source`` where that is still its clip; 0 for a video: the number every message names
    the track's first frame by (:func:`facetransfer.io.frame_numbers.track_first_number`)."""
    from ..io.frame_numbers import track_first_number

    return track_first_number(track)


def posed_extents(rig, activations, rotation, translation, *, chunk: int = 64) -> np.ndarray:
    """Per frame, the box of the face as posed: the points ``(f_0 + sum_j a_j (f_j - f_0)) R^T
    + T`` (the skinned result of the exported rig and animation), their min and max corners.

    Parameters
    ----------
    rig : facetransfer.arkit.ExpressionRig
    activations : (F, 52) float
    rotation : (F, 3, 3) float
        Model-to-camera rotations.
    translation : (F, 3) float
        Model units (:func:`facetransfer.export.common.head_translation`).

    Returns
    -------
    (F, 2, 3) float64
        ``[min, max]`` corners per frame, model units.
    """
    D = rig.deltas.reshape(len(rig.deltas), -1)  # (52, 3n)
    out = np.empty((len(activations), 2, 3))
    for s in range(0, len(activations), chunk):
        a = np.asarray(activations[s:s + chunk], np.float64)
        P = (rig.neutral.ravel() + a @ D).reshape(len(a), -1, 3)  # (f, n, 3)
        # R P^T, (f, 3, n): each axis's n values contiguous, so the min and max below run
        # along memory (over the middle axis of (f, n, 3) they took 4 times as long)
        Q = np.asarray(rotation[s:s + chunk], np.float64) @ np.swapaxes(P, 1, 2)
        T = np.asarray(translation[s:s + chunk], np.float64)
        out[s:s + chunk, 0], out[s:s + chunk, 1] = Q.min(axis=2) + T, Q.max(axis=2) + T
    return out


def _root_extents(root, track, activations, rig, pxr, first: int) -> None:
    """The SkelRoot's ``extent`` at every time code: the posed face's box. UsdGeomBoundable: an
    authored extent stands for the prim's children in bounding-box computations; without one,
    UsdSkel estimates a SkelRoot's from its joints padded by the skinned meshes' authored rest
    extents, which neither follows the blend shapes nor, with no mesh extent, has any size."""
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    box = posed_extents(rig, activations, np.asarray(track.rotation, np.float64),
                        head_translation(track)).astype(np.float32)
    attr = root.CreateExtentAttr()
    for k in range(track.n_frames):
        attr.Set(Vt.Vec3fArray.FromNumpy(box[k]), Usd.TimeCode(first + k))


def _animation(stage, track, activations, pxr, first: int = 0, eyes=None, shown=None):
    """The SkelAnimation: the blend shapes' weights, the head joint's pose and, with ``eyes``
    (:func:`facetransfer.export.gltf_eyes.eye_placement`), each eye joint's turn about its
    centre (:func:`facetransfer.export.gltf_eyes.eye_rotations`) and its scale, 1 or
    :data:`facetransfer.export.gltf_eyes.SHUT_SCALE` where ``shown`` ``(F, 2)`` says its lids
    are shut (:func:`facetransfer.export.gltf_eyes.eyes_shown`)."""
    from .gltf_eyes import eye_rotations, eye_scales, track_eye_gaze

    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    anim = UsdSkel.Animation.Define(stage, "/Face/Skel/Anim")
    anim.CreateJointsAttr(_joints(eyes))
    anim.CreateBlendShapesAttr(list(ARKIT_NAMES))
    w, tr, ro, sc = (anim.CreateBlendShapeWeightsAttr(), anim.CreateTranslationsAttr(),
                     anim.CreateRotationsAttr(), anim.CreateScalesAttr())
    T = head_translation(track).astype(np.float32)
    Q = head_quaternions(track.rotation)[:, None]
    centres = [] if eyes is None else [Gf.Vec3f(*map(float, c)) for c in eyes[0]]
    if eyes is not None:
        Q = np.concatenate([Q, eye_rotations(activations, track_eye_gaze(track, activations))],
                           axis=1)
    S = np.ones((track.n_frames, Q.shape[1]))
    if eyes is not None and shown is not None:
        S[:, 1:] = eye_scales(shown, [1.0, 1.0])
    for k in range(track.n_frames):
        t = Usd.TimeCode(first + k)
        w.Set(Vt.FloatArray.FromNumpy(activations[k].astype(np.float32)), t)
        tr.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, T[k]))] + centres), t)
        ro.Set(Vt.QuatfArray([Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2]))
                              for q in Q[k]]), t)
        sc.Set(Vt.Vec3hArray([Gf.Vec3h(x, x, x) for x in S[k]]), t)
    return anim


def _bind(stage, skel, mesh, pxr, joint: int = 0, deltas=None, names=ARKIT_NAMES) -> None:
    """Bind ``mesh`` rigidly to the skeleton's joint ``joint`` (its points in the head's frame:
    a geometry bind transform of identity), with the blend shapes ``names`` (the 52 ARKit
    names; the SkelAnimation's weights are taken by name) of ``deltas`` ``(len(names), V, 3)``
    where given."""
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(True, 1).Set(Vt.IntArray([joint]))
    binding.CreateJointWeightsPrimvar(True, 1).Set(Vt.FloatArray([1.0]))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1))
    if deltas is not None:
        binding.CreateBlendShapesAttr(list(names))
        binding.CreateBlendShapeTargetsRel().SetTargets(_blend_shapes(stage, mesh, deltas, pxr,
                                                                      names))


def _mouth_inside(stage, skel, rig, model, pxr) -> None:
    """The mouth's inside, ``/Face/mouthInside`` (none without a mouth gap): the glb's cone
    (:func:`facetransfer.export.gltf.mouth_cone`) in the page's cavity colour (:func:`_inside`)."""
    from ..palette import PALETTE
    from .gltf import mouth_cone

    _inside(stage, skel, mouth_cone(model, rig.neutral, list(rig.deltas)), "/Face/mouthInside",
            PALETTE["cavity"], pxr)


def _inside(stage, skel, cone, path: str, colour, pxr) -> None:
    """A cavity's inside at ``path`` (none where ``cone`` is None): the glb's cone
    (:func:`facetransfer.export.viewer.loop_cones`) in the sRGB ``colour``, both sides shown, on
    "head", with 52 blend shapes of its own (the holes' deltas): the mouth's (an open jaw opens
    onto it) and the eye sockets' (the slit of shut lids shows them)."""
    from ..io.exr import srgb_decode

    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    if cone is None:
        return
    P, fan, deltas = cone
    mesh = _tri_mesh(stage, path, P, fan, pxr)
    mesh.CreateDoubleSidedAttr(True)
    lin = srgb_decode(np.asarray(colour, np.uint8))
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(
        Vt.Vec3fArray([Gf.Vec3f(*map(float, lin))]))
    _bind(stage, skel, mesh, pxr, 0, deltas)


def _teeth(stage, skel, rig, model, pxr) -> None:
    """The glb's teeth (:mod:`facetransfer.export.teeth`), vertex ``displayColor``, both sides
    shown, on "head": ``/Face/teethUpper`` rigid, ``/Face/teethLower`` with a blend shape per
    jaw shape (:data:`facetransfer.export.teeth.JAW_SHAPES`: the jaw's rigid motion)."""
    from .teeth import row_moves, teeth_of

    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    teeth = teeth_of(model, rig.neutral, list(rig.deltas))
    if teeth is None:                                   # no landmarks or no mouth gap
        return
    for name, row, fits in (("teethUpper", teeth.upper, {}),
                            ("teethLower", teeth.lower, teeth.fits)):
        mesh = _tri_mesh(stage, f"/Face/{name}", row.points, row.tris, pxr)
        mesh.CreateDoubleSidedAttr(True)
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(
            Vt.Vec3fArray.FromNumpy(row.colours))
        jaw = list(fits)                          # the jaw shapes it follows: none, upper row
        _bind(stage, skel, mesh, pxr, 0, [d for d, _ in row_moves(row, fits, jaw)] or None, jaw)


def _joints(eyes) -> list[str]:
    """The skeleton's joints: ``head``, and with eyes its children ``head/eyeRight``,
    ``head/eyeLeft`` (:data:`facetransfer.export.gltf_eyes.EYE_NODES`)."""
    from .gltf_eyes import EYE_NODES

    return ["head"] + ([] if eyes is None else [f"head/{n}" for n in EYE_NODES])


def _eyeballs(stage, skel, eyes, pxr, rig, model) -> None:
    """The eyeball meshes ``/Face/eyeRight``, ``/Face/eyeLeft``, each bound rigidly to its
    joint (the sphere of :func:`facetransfer.export.gltf_eyes.eyeball_mesh` at the eye's centre
    and radius, its colours as ``displayColor``), and the eye sockets ``/Face/eyeSockets``
    (:func:`facetransfer.export.gltf_eyes.socket_cones`, :func:`_inside`)."""
    from .gltf_eyes import EYE_NODES, eyeball_mesh, socket_colour, socket_cones

    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    _inside(stage, skel, socket_cones(model, rig.neutral, rig.deltas), "/Face/eyeSockets",
            socket_colour(), pxr)
    P, C, T = eyeball_mesh()
    for j, (name, centre, radius) in enumerate(zip(EYE_NODES, *eyes)):
        mesh = _tri_mesh(stage, f"/Face/{name}", P * radius + centre, T, pxr)
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(Vt.Vec3fArray.FromNumpy(C))
        _bind(stage, skel, mesh, pxr, j + 1)


def write_usd(track, model, out: str | os.PathLike, *, overwrite: bool = False,
              first_frame: int = 0, timecode: str | None = None) -> Path:
    """Write the track as USD (``.usd``/``.usdc`` binary, ``.usda`` text) and return the path;
    frame k at time code ``first_frame + k``; ``timecode``, the first frame's SMPTE timecode
    (``HH:MM:SS:FF``), in the root layer's ``customLayerData``."""
    pxr = _pxr()
    Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt = pxr
    if Path(out).suffix.lower() not in USD_SUFFIXES:
        raise ExportError(f"USD output {out} must end in {', '.join(USD_SUFFIXES)}")
    a = require_activations(track)
    rig = identity_rig(track, model)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetTimeCodesPerSecond(track.fps)
    stage.SetFramesPerSecond(track.fps)
    stage.SetStartTimeCode(first_frame)
    stage.SetEndTimeCode(first_frame + track.n_frames - 1)
    root = UsdSkel.Root.Define(stage, "/Face")
    stage.SetDefaultPrim(root.GetPrim())
    from .gltf_eyes import eye_placement, eyes_shown

    eyes = eye_placement(model, rig.neutral)
    skel = UsdSkel.Skeleton.Define(stage, "/Face/Skel")
    skel.CreateJointsAttr(_joints(eyes))
    at = [Gf.Matrix4d(1)] + ([] if eyes is None else [
        Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(*map(float, c))) for c in eyes[0]])
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(at))   # the eyes' centres, in the head's
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(at))   # frame: world = local below head
    anim = _animation(stage, track, a, pxr, int(first_frame), eyes,
                      None if eyes is None else eyes_shown(model, rig, a))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets(
        [anim.GetPath()])
    mesh = _mesh(stage, rig, model, pxr)
    _root_extents(root, track, a, rig, pxr, int(first_frame))
    _bind(stage, skel, mesh, pxr, 0, rig.deltas)
    if eyes is not None:
        _eyeballs(stage, skel, eyes, pxr, rig, model)
    _mouth_inside(stage, skel, rig, model, pxr)
    _teeth(stage, skel, rig, model, pxr)
    meta = {"source": source_name(track.source), "generator": "facetransfer"}
    stage.GetRootLayer().customLayerData = meta if timecode is None else \
        {**meta, "timecode": str(timecode)}
    with atomic_path(out, overwrite=overwrite) as tmp:
        if not stage.GetRootLayer().Export(str(tmp)):
            raise ExportError(f"USD could not write {out}")
    return Path(out)
