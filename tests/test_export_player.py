"""The exported ``.glb`` as an independent player shows it: three.js's GLTFLoader and
AnimationMixer, run in Node, against what the project says the face is.

tests/test_export.py reads the file back with pygltflib and redoes the morph arithmetic itself;
here the file is read by a real player, its own way: morph targets applied with the animation's
weights at time t, the node's rotation and translation at t, metres, glTF's axes (+Y up, +Z the
face's front, +X its left), LINEAR interpolation (slerp for the rotation) and key k at k / fps.
The player is npm's ``three`` at the vendored build's version, installed as a test tool in
``$FACETRANSFER_TEST_TOOLS`` (``.ci/run``); without node or that package the tests skip.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from facetransfer.export import export_track
from facetransfer.export.common import head_translation
from facetransfer.export.gltf import METRES_PER_UNIT
from facetransfer.export.viewer import THREE_VERSION

TOOLS = Path(os.environ.get("FACETRANSFER_TEST_TOOLS",
                            Path.home() / ".cache" / "facetransfer-test-tools"))

# The player: GLTFLoader.parse of the .glb's bytes (no DOM: an embedded PNG is decoded here
# instead of by a browser), the clip played once by an AnimationMixer at each time asked, and
# each vertex as three places it: Mesh.getVertexPosition (the morph targets weighted by
# morphTargetInfluences) then the mesh's matrixWorld. With vertex indices, the base colour
# texture is fetched at their uv attribute as WebGL does (nearest texel; t = 0 is the image's
# first row unless the texture sets flipY; the texture's uv transform applied first).
PLAYER_JS = r"""
import { readFileSync } from 'node:fs';
import { pathToFileURL } from 'node:url';
import { resolveObjectURL } from 'node:buffer';
import { inflateSync } from 'node:zlib';

const args = JSON.parse(process.argv[2]);
const THREE = await import(pathToFileURL(args.three + '/build/three.module.js').href);
const { GLTFLoader } = await import(
  pathToFileURL(args.three + '/examples/jsm/loaders/GLTFLoader.js').href);
globalThis.self = globalThis;  // GLTFLoader reads self.URL for an embedded image

function decodePng(buf) {  // 8-bit RGB or RGBA, not interlaced
  let off = 8, w = 0, h = 0, ct = -1;
  const idat = [];
  while (off < buf.length) {
    const len = buf.readUInt32BE(off), type = buf.toString('latin1', off + 4, off + 8);
    const body = buf.subarray(off + 8, off + 8 + len);
    if (type === 'IHDR') {
      w = body.readUInt32BE(0); h = body.readUInt32BE(4); ct = body[9];
      if (body[8] !== 8 || body[12] !== 0) throw new Error('unsupported PNG');
    } else if (type === 'IDAT') idat.push(body);
    off += 12 + len;
  }
  const bpp = { 2: 3, 6: 4 }[ct];
  if (!bpp) throw new Error('unsupported PNG colour type ' + ct);
  const raw = inflateSync(Buffer.concat(idat)), stride = w * bpp, px = new Uint8Array(h * stride);
  for (let r = 0; r < h; r++) {
    const f = raw[r * (stride + 1)], src = r * (stride + 1) + 1, dst = r * stride;
    for (let i = 0; i < stride; i++) {
      const a = i >= bpp ? px[dst + i - bpp] : 0, b = r > 0 ? px[dst - stride + i] : 0;
      const c = r > 0 && i >= bpp ? px[dst - stride + i - bpp] : 0;
      let p = 0;
      if (f === 1) p = a; else if (f === 2) p = b; else if (f === 3) p = (a + b) >> 1;
      else if (f === 4) {
        const q = a + b - c, pa = Math.abs(q - a), pb = Math.abs(q - b), pc = Math.abs(q - c);
        p = pa <= pb && pa <= pc ? a : (pb <= pc ? b : c);
      }
      px[dst + i] = (raw[src + i] + p) & 255;
    }
  }
  return { data: px, width: w, height: h, channels: bpp };
}

const pngLoader = {  // in place of the browser's image decoding: the blob: URL's bytes
  setCrossOrigin() { return this; }, setRequestHeader() { return this; },
  load(url, onLoad, onProgress, onError) {
    resolveObjectURL(url).arrayBuffer()
      .then((ab) => onLoad(new THREE.Texture(decodePng(Buffer.from(ab))))).catch(onError);
  },
};

const loader = new GLTFLoader();
loader.register((parser) => { parser.textureLoader = pngLoader; return { name: 'node_png' }; });
const bytes = readFileSync(args.glb);
const gltf = await loader.parseAsync(
  bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.length), '');
let mesh = null;
gltf.scene.traverse((o) => { if (o.isMesh && mesh === null) mesh = o; });
const clip = gltf.animations[0];
const mixer = new THREE.AnimationMixer(gltf.scene);
const action = mixer.clipAction(clip);
action.setLoop(THREE.LoopOnce, 1);  // the last key is the clip's end, not a wrap to 0
action.clampWhenFinished = true;
action.play();

const n = mesh.geometry.attributes.position.count, v = new THREE.Vector3();
const frames = [];
for (const t of args.times) {
  mixer.setTime(t);
  gltf.scene.updateMatrixWorld(true);
  const pos = new Array(3 * n);
  for (let i = 0; i < n; i++) {
    mesh.getVertexPosition(i, v).applyMatrix4(mesh.matrixWorld);
    pos[3 * i] = v.x; pos[3 * i + 1] = v.y; pos[3 * i + 2] = v.z;
  }
  frames.push({ t, influences: Array.from(mesh.morphTargetInfluences), positions: pos });
}
// the triangles three draws front side out: counter-clockwise, the way the normals point
const idx = mesh.geometry.index, nrm = mesh.geometry.attributes.normal, tri = new THREE.Triangle();
const fn = new THREE.Vector3(), vn = new THREE.Vector3(), a = new THREE.Vector3();
let outward = 0;
for (let f = 0; f < idx.count; f += 3) {
  const i = idx.getX(f), j = idx.getX(f + 1), k = idx.getX(f + 2);
  tri.setFromAttributeAndIndices(mesh.geometry.attributes.position, i, j, k).getNormal(fn);
  vn.fromBufferAttribute(nrm, i).add(a.fromBufferAttribute(nrm, j))
    .add(a.fromBufferAttribute(nrm, k));
  if (fn.dot(vn) > 0) outward++;
}
const dict = mesh.morphTargetDictionary || {};
const out = { revision: THREE.REVISION, duration: clip.duration, frames,
  local: Array.from(mesh.geometry.attributes.position.array),
  side: mesh.material.side === THREE.FrontSide ? 'front' : 'other',
  outward: outward / (idx.count / 3),
  targetNames: Object.keys(dict).sort((a, b) => dict[a] - dict[b]) };

const map = mesh.material.map;
if (map && args.uv_vertices) {
  map.updateMatrix();
  const uv = mesh.geometry.attributes[map.channel === 0 ? 'uv' : 'uv' + map.channel];
  const img = map.image, samples = [];
  for (const i of args.uv_vertices) {
    const p = new THREE.Vector2(uv.getX(i), uv.getY(i)).applyMatrix3(map.matrix);
    const t = map.flipY ? 1 - p.y : p.y;
    const col = Math.min(img.width - 1, Math.max(0, Math.floor(p.x * img.width)));
    const row = Math.min(img.height - 1, Math.max(0, Math.floor(t * img.height)));
    const k = (row * img.width + col) * img.channels;
    samples.push([img.data[k], img.data[k + 1], img.data[k + 2]]);
  }
  out.texture = { flipY: map.flipY, size: [img.width, img.height], samples };
}
process.stdout.write(JSON.stringify(out));
"""


def _play(glb: Path, times, tmp_path: Path, uv_vertices=None) -> dict:
    """What three.js shows of ``glb`` at ``times`` (seconds)."""
    node = shutil.which("node")
    three = TOOLS / "node_modules" / "three"
    if node is None or not (three / "package.json").is_file():
        pytest.skip(f"node or the npm package three (in {TOOLS}) is not installed (.ci/run)")
    version = json.loads((three / "package.json").read_text())["version"]
    if version != THREE_VERSION:
        pytest.skip(f"three {version} is installed in {TOOLS}, not the vendored build's "
                    f"{THREE_VERSION} (.ci/run installs it)")
    script = tmp_path / "player.mjs"
    script.write_text(PLAYER_JS)
    args = {"three": str(three), "glb": str(glb), "times": [float(t) for t in times],
            "uv_vertices": None if uv_vertices is None else [int(i) for i in uv_vertices]}
    res = subprocess.run([node, str(script), json.dumps(args)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout)
    assert out["revision"] == THREE_VERSION.split(".")[1]
    return out


def _face(model, weights, rotation, translation_units) -> np.ndarray:
    """The face as the project says it is: the model's mesh of ``weights`` in metres, turned by
    the head's model-to-camera ``rotation`` and moved by its translation (export/common.py)."""
    V = model.synthesize(weights).reshape(-1, 3) * METRES_PER_UNIT
    return V @ np.asarray(rotation).T + np.asarray(translation_units) * METRES_PER_UNIT


@pytest.fixture(scope="module")
def case(arkit_model, make_arkit_track, tmp_path_factory):
    track, a, _ = make_arkit_track(arkit_model, 6)
    out = export_track(track, "glb", tmp_path_factory.mktemp("player") / "face.glb",
                       model=arkit_model)
    return arkit_model, track, a, out


def test_three_plays_the_tracked_face(case, tmp_path):
    from scipy.spatial.transform import Rotation, Slerp

    from facetransfer.arkit import ARKIT_NAMES

    model, track, a, glb = case
    fps, F = track.fps, track.n_frames
    keys = [0, 2, F - 1]
    mid = 3  # half-way between keys 3 and 4
    times = [k / fps for k in keys] + [(mid + 0.5) / fps]
    shown = _play(glb, times, tmp_path)
    assert shown["targetNames"] == list(ARKIT_NAMES)
    assert shown["duration"] == pytest.approx((F - 1) / fps, abs=1e-6)
    T = head_translation(track)
    err, influence_err = {}, {}
    for k, fr in zip(keys, shown["frames"]):
        influence_err[k] = float(np.abs(np.subtract(fr["influences"], a[k])).max())
        got = np.reshape(fr["positions"], (-1, 3))
        want = _face(model, track.weights_at(k), track.rotation[k], T[k])
        err[k] = float(np.abs(got - want).max())
    # half-way: LINEAR is a lerp of the weights (the face is linear in them) and translation,
    # a slerp of the rotation (glTF 2.0, Animations: interpolation)
    w = {n: (track.weights[n][mid] + track.weights[n][mid + 1]) / 2 for n in track.mode_names}
    R = Slerp([0.0, 1.0], Rotation.from_matrix(track.rotation[mid:mid + 2]))(0.5).as_matrix()
    got = np.reshape(shown["frames"][-1]["positions"], (-1, 3))
    err[mid + 0.5] = float(np.abs(got - _face(model, w, R, (T[mid] + T[mid + 1]) / 2))
                           .max())
    print("three vs the project, max vertex error (m) at frame:", err)
    assert max(err.values()) < 1e-5, err
    assert max(influence_err.values()) < 1e-6, influence_err  # key k is frame k's activations
    # the frames differ by far more than that (the comparison can fail)
    apart = np.abs(_face(model, track.weights_at(mid), track.rotation[mid], T[mid])
                   - _face(model, track.weights_at(mid + 1), track.rotation[mid + 1],
                           T[mid + 1])).max()
    assert apart > 1e-3


def test_three_sees_glTFs_axes_and_metres(case, tmp_path):
    """The rest mesh in glTF's frame: +Y up, the face's front +Z, its left +X (glTF 2.0,
    Coordinate system and units), a head's size in metres, its front faces outward; and the
    head's place in the world on the side of the image the track saw it."""
    model, track, _, glb = case
    shown = _play(glb, [0.0], tmp_path)
    V = np.reshape(shown["local"], (-1, 3))
    L = V[np.asarray(model.landmarks)]  # the 68-point scheme
    right_eye, left_eye = L[36:42].mean(axis=0), L[42:48].mean(axis=0)
    brows, chin, nose_tip = L[17:27].mean(axis=0), L[8], L[30]
    assert left_eye[0] - right_eye[0] > 0.04  # the subject's left at +X, ~6 cm between the eyes
    assert left_eye[0] - right_eye[0] < 0.09
    assert brows[1] - chin[1] > 0.08  # up is +Y, ~10-13 cm from chin to brows
    assert brows[1] - chin[1] < 0.2
    assert nose_tip[2] > (left_eye[2] + right_eye[2]) / 2 + 0.01  # the nose points to +Z
    # three culls back faces of a single-sided material: the triangles wind counter-clockwise
    # seen from outside (glTF's front face), the way the normals point
    assert shown["side"] == "front" and shown["outward"] > 0.99
    # the head where the image shows it: right of the frame's centre is +X, above it is +Y
    world = np.reshape(shown["frames"][0]["positions"], (-1, 3))
    centre = world[np.asarray(model.landmarks)].mean(axis=0)
    (tx, ty), (W, H) = track.translation[0], track.frame_size
    assert np.sign(centre[0]) == np.sign(tx - W / 2) and np.sign(centre[1]) == np.sign(H / 2 - ty)


def test_three_shows_the_texture_the_right_way_up(case, tmp_path):
    """The base colour three fetches at a vertex's uv is the project's texture lookup at that
    vertex (render.sample_texture: row 0 of the image is v = 1)."""
    from facetransfer.render.shading import sample_texture

    model, track, _, _ = case
    size = 256
    rows, cols = np.mgrid[0:size, 0:size]
    tex = np.stack([rows, cols, np.full_like(rows, 128)], axis=-1).astype(np.uint8)
    glb = export_track(track, "glb", tmp_path / "textured.glb", model=model, texture=tex)
    idx = np.arange(0, model.n_vertices, 37)
    shown = _play(glb, [0.0], tmp_path, uv_vertices=idx)
    got = np.asarray(shown["texture"]["samples"], np.float64)
    want = sample_texture(tex, np.asarray(model.uvs)[idx])
    assert np.ptp(want[:, 0]) > 150 and np.ptp(want[:, 1]) > 150  # a flip would show
    # the project's texel centres are corner-aligned, WebGL's at half texels: within 2 levels
    np.testing.assert_allclose(got, want, atol=2.0)


def test_three_plays_sparse_morph_targets(case, tmp_path, monkeypatch):
    """A rig whose targets move a part of the face each (the 5 % of the vertices a target moves
    most; target 0 none) is written as sparse accessors (and one without data), and three
    plays it as that rig's face: the neutral plus the weighted deltas, posed."""
    import dataclasses

    import pygltflib

    from facetransfer.export import gltf
    from facetransfer.export.common import identity_rig

    model, track, a, _ = case
    rig = identity_rig(track, model)
    deltas = np.array(rig.deltas, copy=True)
    for j, d in enumerate(deltas):
        size = np.linalg.norm(d, axis=1)
        d[size < (np.inf if j == 0 else np.quantile(size, 0.95))] = 0.0
    local = dataclasses.replace(rig, deltas=deltas)
    monkeypatch.setattr(gltf, "identity_rig", lambda tr, m: local)
    glb = export_track(track, "glb", tmp_path / "sparse.glb", model=model)
    g = pygltflib.GLTF2().load(str(glb))
    kinds = [g.accessors[t[k]] for t in g.meshes[0].primitives[0].targets
             for k in ("POSITION", "NORMAL")]
    assert all(x.bufferView is None for x in kinds)
    assert sum(x.sparse is not None for x in kinds) >= 100  # targets 1-50 (51 has no deltas)
    k = 4
    shown = _play(glb, [k / track.fps], tmp_path)
    got = np.reshape(shown["frames"][0]["positions"], (-1, 3))
    T = head_translation(track)
    face = (local.neutral + np.tensordot(a[k].astype(np.float64), deltas, 1)) * METRES_PER_UNIT
    want = face @ track.rotation[k].T + T[k] * METRES_PER_UNIT
    err = float(np.abs(got - want).max())
    print("three vs the sparse rig's face, max vertex error (m):", err)
    assert err < 1e-5
    # a player that read the sparse targets as zeros would show the neutral: far off
    rest = (local.neutral * METRES_PER_UNIT) @ track.rotation[k].T + T[k] * METRES_PER_UNIT
    assert np.abs(rest - want).max() > 1e-3
