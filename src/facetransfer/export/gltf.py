"""glTF 2.0 binary (``.glb``): the clip's person with 52 ARKit morph targets and the performance.

The file holds a node ``face`` with the face mesh: the person's neutral face (the track's identity,
Eq. (9)) with the template's UVs (v flipped: glTF's origin is the image's top left), vertex
normals, optionally the texture lifted from the video as its base colour, and 52 morph targets
(``POSITION`` deltas ``f_j - f_0``, :func:`facetransfer.arkit.expression_rig`, and ``NORMAL``
deltas, the shape's vertex normals minus the rest's, so that a player which does not recompute
normals shades an open jaw as open) named in
``mesh.extras.targetNames`` in :data:`facetransfer.arkit.ARKIT_NAMES` order (the convention
three.js, Blender and Babylon read). One animation ``performance`` has a ``weights`` channel with
one key per frame (time ``k / fps``, LINEAR) whose values are the track's activations, and the
head pose as the node's ``rotation`` and ``translation`` channels (same keys). Behind the
face's eye holes, two eyeball nodes (``eyeRight``, ``eyeLeft``: children of ``face``, one
shared ``eyeball`` mesh) turned by the gaze of :func:`.gltf_eyes.track_eye_gaze` (a take's
recorded eye angles, else the eyeLook* curves), a ``rotation`` channel each, and hidden while
their lids are shut, a ``scale`` channel each (STEP: the radius, or nearly 0; not for a model
without landmarks); the mouth's inside, a second primitive of the face mesh with its own morph
targets (:func:`_mouth_inside`): the lips' gap no longer shows what is behind the head; then
the upper and the lower teeth, two more primitives on the dental arches behind the lips
(:func:`.teeth.gltf_primitives`: the upper row rigid, the lower moved by the jaw shapes'
targets), so an open jaw shows teeth; and last the eye sockets, a dark cone behind each eye
hole, one more primitive (:func:`_eyes`): the slit the shut lids leave shows them, not the
eyeball. Positions are in metres (glTF's unit): model units times ``metres_per_unit`` (0.01
for the ICT-FaceKit's centimetres).

Each target's ``POSITION`` and ``NORMAL`` accessor is stored the smallest exact way
(:func:`morph_encoding`): as an accessor without data when every delta is zero (read as
zeros), as a sparse accessor of the vertices that move when that is smaller, else densely; no
delta is rounded or dropped. The default model's targets move every vertex (a person's shapes
are made by deformation transfer, a global solve, through the model's truncated identity mode;
the FaceKit's own ``eyeBlink_L`` moves 57 % of its head's vertices): only the all-zero
``tongueOut`` saves its bytes there (BENCHMARKS.md, forty-fifth session, helper glb).

Written with pygltflib; every file the tests write passes the Khronos glTF validator.

References
----------
Khronos glTF 2.0 specification, §3.6.2 Accessors (an undefined ``bufferView`` is zeros;
Sparse Accessors), §3.7.2.2 Morph Targets, §3.11 Animations.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from ..arkit import ARKIT_NAMES
from ..io.atomic import atomic_path
from .common import (ExportError, head_quaternions, head_translation, identity_rig,
                     require_activations, source_name)

__all__ = ["METRES_PER_UNIT", "write_glb", "texture_image", "texture_png",
           "lift_clip_texture", "check_texture_video", "morph_encoding", "mouth_cone"]

#: Model units to metres (the ICT-FaceKit is in centimetres).
METRES_PER_UNIT = 0.01

_ARRAY, _ELEMENTS = 34962, 34963
_FLOAT, _UINT, _USHORT = 5126, 5125, 5123


def morph_encoding(a: np.ndarray) -> str:
    """How a morph target's deltas ``a`` ``(n, 3) float32`` are stored, the smallest exact way.

    Returns
    -------
    str
        ``"zeros"`` (every delta 0: an accessor without ``bufferView``, which glTF 2.0 defines
        as zeros), ``"sparse"`` (glTF 2.0 §3.6.2, Sparse Accessors: the rows with a nonzero
        component, each an index of 2 bytes up to 65536 vertices, else 4, and 12 bytes of
        values) when that is fewer bytes than ``"dense"`` (12 bytes a row). No delta is rounded
        or dropped: a row is left out only when its three components are 0.0 or -0.0 (read
        back as 0.0).
    """
    moved = int(np.count_nonzero((a != 0).any(axis=1)))
    if moved == 0:
        return "zeros"
    index = 2 if len(a) - 1 <= 0xFFFF else 4
    dense = a.shape[1] * 4 * len(a)
    sparse = moved * (index + a.shape[1] * 4) + (-moved * index) % 4
    return "sparse" if sparse < dense else "dense"


class _Blob:
    """The binary chunk: aligned views and accessors appended one by one."""

    def __init__(self, gltf):
        self.gltf = gltf
        self.buf = io.BytesIO()

    def view(self, data: bytes, target: int | None = None) -> int:
        from pygltflib import BufferView

        pad = (-self.buf.tell()) % 4
        self.buf.write(b"\0" * pad)
        off = self.buf.tell()
        self.buf.write(data)
        self.gltf.bufferViews.append(BufferView(buffer=0, byteOffset=off, byteLength=len(data),
                                                target=target))
        return len(self.gltf.bufferViews) - 1

    def accessor(self, a: np.ndarray, kind: str, *, target: int | None = _ARRAY,
                 bounds: bool = False) -> int:
        from pygltflib import Accessor

        comp = _UINT if a.dtype == np.uint32 else _FLOAT
        view = self.view(np.ascontiguousarray(a).tobytes(), target)
        flat = a.reshape(len(a), -1)
        acc = Accessor(bufferView=view, componentType=comp, count=int(len(a)), type=kind)
        if bounds:
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
            if comp == _UINT:
                acc.min, acc.max = [int(x) for x in acc.min], [int(x) for x in acc.max]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def morph_accessor(self, a: np.ndarray, *, bounds: bool = False) -> int:
        """A morph target's ``(n, 3) float32`` deltas as :func:`morph_encoding` says; ``min``
        and ``max`` (``bounds``) are over all ``n`` rows, the implied zeros too."""
        from pygltflib import Accessor, AccessorSparseIndices, AccessorSparseValues, Sparse

        how = morph_encoding(a)
        if how == "dense":
            return self.accessor(a, "VEC3", bounds=bounds)
        acc = Accessor(byteOffset=None, componentType=_FLOAT, count=int(len(a)), type="VEC3")
        if how == "sparse":
            rows = np.flatnonzero((a != 0).any(axis=1))
            idx = rows.astype(np.uint16 if len(a) - 1 <= 0xFFFF else np.uint32)
            acc.sparse = Sparse(
                count=int(len(rows)),
                indices=AccessorSparseIndices(bufferView=self.view(idx.tobytes()),
                                              componentType=_USHORT if idx.dtype == np.uint16
                                              else _UINT),
                values=AccessorSparseValues(
                    bufferView=self.view(np.ascontiguousarray(a[rows], np.float32).tobytes())))
        if bounds:
            acc.min = [float(x) for x in a.min(axis=0)]
            acc.max = [float(x) for x in a.max(axis=0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1


def _square_texture(size, what: str) -> None:
    """ExportError unless ``size`` ``(W, H)`` is square
    (:func:`facetransfer.texture.base.check_square_texture`)."""
    from ..texture.base import check_square_texture

    check_square_texture(size, what, ExportError)


def texture_image(path):
    """The PIL image (not yet decoded) of a texture file that can be the template's UV
    texture: an image (not a video), square (:func:`_square_texture`).

    Raises
    ------
    ExportError
        Naming the file: a video, unreadable, or not square.
    """
    from PIL import Image

    from ..io.npz import check_input_file
    from ..io.video_options import VIDEO_SUFFIXES

    p = Path(path)
    if p.suffix.lower() in VIDEO_SUFFIXES:
        raise ExportError(f"texture image {p} is a video: a texture is an image in the "
                          f"template's UV layout; to lift one from the video, give "
                          f"--texture-from {p}")
    check_input_file(p, "texture image", ExportError)
    try:
        img = Image.open(p)
    except Image.DecompressionBombError:           # Pillow's limit on pixels read at once
        raise ExportError(f"texture image {p} has more than {2 * Image.MAX_IMAGE_PIXELS:,} "
                          f"pixels, more than the image reader takes: give a smaller "
                          f"texture") from None
    except (OSError, ValueError) as exc:
        raise ExportError(f"cannot read texture image {p} ({exc})") from None
    _square_texture(img.size, f"texture image {p}")
    return img


def texture_png(texture) -> bytes:
    """PNG bytes of a texture given as an image path or an ``(H, W, 3)`` uint8 RGB array
    (square: :func:`texture_image`)."""
    from PIL import Image

    if isinstance(texture, (str, os.PathLike)):
        img = texture_image(texture)
        try:
            img = _rgb8(img)
        except (OSError, ValueError) as exc:       # its pixels: e.g. a file cut short
            raise ExportError(f"cannot read texture image {texture} ({exc})") from None
    else:
        a = np.asarray(texture)
        if a.ndim != 3 or a.shape[2] != 3:
            raise ExportError(f"texture must be (H, W, 3), got {a.shape}")
        _square_texture(a.shape[1::-1], "the texture")
        img = Image.fromarray(np.clip(a, 0, 255).astype(np.uint8), "RGB")
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()


def _rgb8(img):
    """A PIL image as 8-bit RGB: a 16-bit grey one (PIL's ``I;16`` or ``I``) as
    ``round(v / 257)`` in each channel (:func:`facetransfer.io.frame_file.shown_16`, as a
    16-bit plate's frame is seen; PIL's own conversion clips it at 255, a white texture); any
    other by PIL (a 16-bit RGB PNG it reads in 8)."""
    from PIL import Image

    if img.mode.startswith("I;16") or img.mode == "I":
        from ..io.frame_file import shown_16

        return Image.fromarray(shown_16(np.clip(np.asarray(img), 0, 65535)), "RGB")
    return img.convert("RGB")


def check_texture_video(track, video) -> None:
    """TrackError (VideoError: not a video) unless ``video`` is one ``track`` can lift a
    texture from: its frame size, and at least the track's frames (a track of its first
    frames lifts from those)."""
    from ..io.video import video_info

    info = video_info(video)
    track.check_video(min(info.n_frames, track.n_frames) if info.n_frames else info.n_frames,
                      info.size, what=f"video {video}")


def lift_clip_texture(track, model, video, *, tex_size: int = 512, step: int = 10,
                      progress=None) -> np.ndarray:
    """The face's texture lifted from its video (§6, Eq. (L1) weights), merged over every
    ``step``-th frame and hole-filled, in the template's UV layout.

    A track of the video's first frames only (``track --max-frames``) lifts from those.

    Returns
    -------
    (tex_size, tex_size, 3) uint8
        Row 0 is ``v = 1`` (glTF's top-left origin after the exporter's ``1 - v``).
    """
    import itertools

    from ..io.video import iter_frames
    from ..texture import lift_merged, texture_to_uint8

    check_texture_video(track, video)
    merged, _ = lift_merged(model, itertools.islice(iter_frames(video), track.n_frames), track,
                            tex_size=tex_size, step=step, progress=progress)
    return texture_to_uint8(merged.texture)


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals ``(n, 3) float32``: the renderer's (area-weighted), so a glb shades
    like our own renders; (0, 0, 1) where a vertex has none."""
    from ..geometry import vertex_normals

    n = vertex_normals(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    n = n.astype(np.float32)
    bad = ~np.isfinite(n).all(axis=1) | (np.linalg.norm(n, axis=1) < 0.5)
    n[bad] = (0.0, 0.0, 1.0)
    return (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)


def _material(gltf, blob: _Blob, texture) -> int:
    from pygltflib import (Image, Material, PbrMetallicRoughness, Sampler, Texture,
                           TextureInfo)

    pbr = PbrMetallicRoughness(baseColorFactor=[0.86, 0.72, 0.64, 1.0], metallicFactor=0.0,
                               roughnessFactor=0.7)
    if texture is not None:
        view = blob.view(texture_png(texture))
        gltf.images.append(Image(bufferView=view, mimeType="image/png"))
        gltf.samplers.append(Sampler(magFilter=9729, minFilter=9729, wrapS=33071, wrapT=33071))
        gltf.textures.append(Texture(source=0, sampler=0))
        pbr.baseColorFactor = [1.0, 1.0, 1.0, 1.0]
        pbr.baseColorTexture = TextureInfo(index=0)
    gltf.materials.append(Material(name="skin", pbrMetallicRoughness=pbr, doubleSided=False))
    return 0


def _mesh(gltf, blob: _Blob, rig, model, unit: float, material: int) -> None:
    from pygltflib import Attributes, Mesh, Primitive

    V = (rig.neutral * unit).astype(np.float32)
    faces = np.asarray(model.faces, np.int64)
    N = _normals(V, faces)
    attrs = Attributes(POSITION=blob.accessor(V, "VEC3", bounds=True),
                       NORMAL=blob.accessor(N, "VEC3"))
    if model.uvs is not None:
        uv = np.asarray(model.uvs, np.float64).copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # glTF's texture origin is top left
        attrs.TEXCOORD_0 = blob.accessor(uv.astype(np.float32), "VEC2")
    targets = []
    for d in rig.deltas:     # a shape's normals too: players that keep the rest's (three.js,
        D = (d * unit).astype(np.float32)          # glTFast, Godot) shade it as the rest
        targets.append(Attributes(POSITION=blob.morph_accessor(D, bounds=True),
                                  NORMAL=blob.morph_accessor(_normals(V + D, faces) - N)))
    idx = faces.astype(np.uint32).reshape(-1, 1)
    prim = Primitive(attributes=attrs, indices=blob.accessor(idx, "SCALAR", target=_ELEMENTS),
                     material=material, targets=targets)
    from .teeth import gltf_primitives

    moved = [(d * unit) for d in rig.deltas]
    prims = [prim] + _mouth_inside(gltf, blob, model, V, moved) + gltf_primitives(
        gltf, blob, model, V, moved)             # the teeth: after the mouth's inside
    gltf.meshes.append(Mesh(name="face", primitives=prims, weights=[0.0] * len(rig.deltas),
                            extras={"targetNames": list(ARKIT_NAMES)}))


def mouth_cone(model, neutral: np.ndarray, deltas: list):
    """The mouth's inside as the `view` page closes it
    (:func:`facetransfer.export.viewer.loop_cones`): a cone from the inner lips' loop
    (:func:`facetransfer.topology.mesh_topology`) to a point behind its middle by
    :data:`facetransfer.export.viewer.CAVITY_DEPTH` of its width; ``(points (k+1, 3), fan (k,
    3), [deltas (k+1, 3) per shape])``, None without a mouth gap."""
    from ..topology import mesh_topology
    from .viewer import CAVITY_DEPTH, loop_cones

    loop = mesh_topology(model).mouth_loop
    return loop_cones(neutral, deltas, [(loop, CAVITY_DEPTH["mouth"])]) if loop.size else None


def _mouth_inside(gltf, blob: _Blob, model, V: np.ndarray, deltas: list) -> list:
    """The mouth's inside, a second primitive of the face mesh (:func:`mouth_cone`, none
    without a mouth gap; :func:`_inside`), in the `view` page's cavity colour."""
    from ..palette import PALETTE

    return _inside(gltf, blob, mouth_cone(model, V, deltas), "mouth", PALETTE["cavity"])


def _inside(gltf, blob: _Blob, cone, name: str, colour) -> list:
    """A cavity's inside (``cone`` of :func:`facetransfer.export.viewer.loop_cones`, none where
    it is None), a primitive of the face mesh with its own morph targets (the holes' deltas),
    in the sRGB ``colour``, both sides shown: the mouth's (an open jaw opens onto it; before, a
    player showed what was behind the head there) and the eye sockets'
    (:func:`.gltf_eyes.socket_cones`: the slit of shut lids shows them)."""
    from pygltflib import Attributes, Material, PbrMetallicRoughness, Primitive

    from ..io.exr import srgb_decode

    if cone is None:
        return []
    P, fan, cone_deltas = cone
    lin = srgb_decode(np.asarray(colour, np.uint8))
    gltf.materials.append(Material(name=name, doubleSided=True,
                                   pbrMetallicRoughness=PbrMetallicRoughness(
                                       baseColorFactor=[float(c) for c in lin] + [1.0],
                                       metallicFactor=0.0, roughnessFactor=1.0)))
    targets = [Attributes(POSITION=blob.morph_accessor(D, bounds=True)) for D in cone_deltas]
    return [Primitive(attributes=Attributes(POSITION=blob.accessor(P, "VEC3", bounds=True)),
                      indices=blob.accessor(fan.astype(np.uint32).reshape(-1, 1), "SCALAR",
                                            target=_ELEMENTS),
                      material=len(gltf.materials) - 1, targets=targets)]


def _eyes(gltf, blob: _Blob, model, rig, unit: float) -> list[int]:
    """The eyeball nodes (:mod:`facetransfer.export.gltf_eyes`), children of node 0, and
    their mesh and material; their indices, none for a model without landmarks. And the eye
    sockets (:func:`.gltf_eyes.socket_cones`), a primitive of the face mesh (:func:`_inside`)."""
    from pygltflib import Attributes, Material, Mesh, Node, PbrMetallicRoughness, Primitive

    from .gltf_eyes import EYE_NODES, eye_placement, eyeball_mesh, socket_colour, socket_cones

    sockets = socket_cones(model, (rig.neutral * unit).astype(np.float32), rig.deltas * unit)
    gltf.meshes[0].primitives += _inside(gltf, blob, sockets, "eyeSocket", socket_colour())
    placed = eye_placement(model, rig.neutral)
    if placed is None:
        return []
    P, C, T = eyeball_mesh()
    gltf.materials.append(Material(name="eye", pbrMetallicRoughness=PbrMetallicRoughness(
        baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0, roughnessFactor=0.3)))
    prim = Primitive(attributes=Attributes(POSITION=blob.accessor(P, "VEC3", bounds=True),
                                           NORMAL=blob.accessor(P, "VEC3"),
                                           COLOR_0=blob.accessor(C, "VEC3")),
                     indices=blob.accessor(T, "SCALAR", target=_ELEMENTS),
                     material=len(gltf.materials) - 1)
    gltf.meshes.append(Mesh(name="eyeball", primitives=[prim]))
    nodes = []
    for name, centre, radius in zip(EYE_NODES, *placed):
        gltf.nodes.append(Node(name=name, mesh=len(gltf.meshes) - 1,
                               translation=[float(x) for x in centre * unit],
                               scale=[float(radius * unit)] * 3))
        nodes.append(len(gltf.nodes) - 1)
    return nodes


def _animation(gltf, blob: _Blob, track, activations: np.ndarray, unit: float,
               eyes: list[int], shown: np.ndarray | None = None) -> None:
    """The animation ``performance``: the face's weights and pose, LINEAR, and each eye's turn
    (LINEAR) and, with ``shown`` ``(F, 2)`` (:func:`.gltf_eyes.eyes_shown`), its ``scale``
    (STEP): the node's radius while shown, :data:`.gltf_eyes.SHUT_SCALE` of it while shut."""
    from pygltflib import Animation, AnimationChannel, AnimationChannelTarget, AnimationSampler

    from .gltf_eyes import eye_rotations, eye_scales, track_eye_gaze

    t = (np.arange(track.n_frames) / track.fps).astype(np.float32).reshape(-1, 1)
    inp = blob.accessor(t, "SCALAR", target=None, bounds=True)
    outs = [(0, "weights", activations.reshape(-1, 1).astype(np.float32), "SCALAR"),
            (0, "rotation", head_quaternions(track.rotation).astype(np.float32), "VEC4"),
            (0, "translation", (head_translation(track) * unit).astype(np.float32), "VEC3")]
    if eyes:
        q = eye_rotations(activations, track_eye_gaze(track, activations)).astype(np.float32)
        outs += [(node, "rotation", np.ascontiguousarray(q[:, k]), "VEC4")
                 for k, node in enumerate(eyes)]
    if eyes and shown is not None:
        sc = eye_scales(shown, [gltf.nodes[node].scale[0] for node in eyes]).astype(np.float32)
        outs += [(node, "scale", np.repeat(sc[:, k, None], 3, axis=1), "VEC3")
                 for k, node in enumerate(eyes)]
    anim = Animation(name="performance")
    for i, (node, path, a, kind) in enumerate(outs):
        anim.samplers.append(AnimationSampler(input=inp, output=blob.accessor(a, kind, target=None),
                                              interpolation="STEP" if path == "scale"
                                              else "LINEAR"))
        anim.channels.append(AnimationChannel(sampler=i,
                                              target=AnimationChannelTarget(node=node, path=path)))
    gltf.animations.append(anim)


def write_glb(track, model, out: str | os.PathLike, *, overwrite: bool = False, texture=None,
              metres_per_unit: float = METRES_PER_UNIT, timecode: str | None = None) -> Path:
    """Write the track as a glTF 2.0 binary with ARKit morph targets and return the path.

    Parameters
    ----------
    track : Track
        With ``blendshapes``.
    model : MultilinearModel
        The track's model (ARKit-named expressions).
    texture : path or (H, W, 3) uint8, optional
        Base colour in the template's UV layout (e.g. lifted from the video).
    metres_per_unit : float
        Model units to metres.
    timecode : str, optional
        The first frame's SMPTE timecode (``HH:MM:SS:FF``), in the file's ``extras``.
    """
    from pygltflib import GLTF2, Asset, Buffer, Node, Scene

    from .gltf_eyes import eyes_shown

    a = require_activations(track)
    rig = identity_rig(track, model)
    gltf = GLTF2(asset=Asset(version="2.0", generator="facetransfer"))
    blob = _Blob(gltf)
    _mesh(gltf, blob, rig, model, float(metres_per_unit), _material(gltf, blob, texture))
    q0 = head_quaternions(track.rotation[:1])[0]
    gltf.nodes.append(Node(name="face", mesh=0, rotation=[float(x) for x in q0],
                           translation=[float(x) for x in head_translation(track)[0]
                                        * metres_per_unit]))
    eyes = _eyes(gltf, blob, model, rig, float(metres_per_unit))
    gltf.nodes[0].children = eyes
    gltf.scenes.append(Scene(name="facetransfer", nodes=[0]))
    gltf.scene = 0
    _animation(gltf, blob, track, a, float(metres_per_unit), eyes,
               eyes_shown(model, rig, a) if eyes else None)
    pad = (-blob.buf.tell()) % 4
    blob.buf.write(b"\0" * pad)
    data = blob.buf.getvalue()
    gltf.buffers.append(Buffer(byteLength=len(data)))
    gltf.set_binary_blob(data)
    gltf.extras = {"source": source_name(track.source), "fps": track.fps} | (
        {} if timecode is None else {"timecode": str(timecode)})
    with atomic_path(out, overwrite=overwrite) as tmp:
        gltf.save_binary(str(tmp))
    return Path(out)
