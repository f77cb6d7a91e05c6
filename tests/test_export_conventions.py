"""What a take's and a glb's, a USD's and the dial page's numbers mean to the tools that read them.

Reference facts:

* Unreal's Live Link Face importer (Epic's ``LiveLinkFaceImporterFactory``) requires the header
  to start ``Timecode,BlendShapeCount``, takes a take's frame rate to be 60 where some row's
  ``FF.mmm`` passes 30 and 30 otherwise (the app records at one of the two), and places a row
  at ``HH*3600 + MM*60 + SS + FF.mmm / rate`` seconds (:func:`_unreal_seconds` does the same
  sums).
* Three takes written by the Live Link Face app (public: ``MySlate_1_iPhone.csv`` of
  dwskillman/BlendFiles, ``anim/alex_rom_3.csv`` and ``anim/alex_rom_4.csv`` of
  alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder; 679, 4030 and 3809 rows), each eye
  column fitted by least squares against its eye's curves (correlation 0.994-1.000):
  ``LeftEyeYaw`` = +0.591 / +0.607 / +0.594 radians per unit of ``EyeLookInLeft -
  EyeLookOutLeft``, ``RightEyeYaw`` = -0.612 / -0.603 / -0.592 per unit of ``EyeLookInRight -
  EyeLookOutRight``, each eye's pitch = +0.611 / +0.556 / +0.544 per unit of ``EyeLookDown -
  EyeLookUp`` (both eyes alike), plus a constant of about -0.065 (left yaw), +0.065 (right
  yaw), 0-0.02 (pitch). Rows where ``EyeLookInLeft`` passes 0.3 average ``LeftEyeYaw``
  +0.43 / +0.37 (alex_rom_3 / 4), where ``EyeLookOutLeft`` does -0.57 / -0.58. So in the app's
  columns an eye's yaw is positive toward the subject's right (the gaze ``EyeLookInLeft`` and
  ``EyeLookOutRight`` name) and its pitch positive looking down, in radians (±0.6: 34°). One
  row alone misleads: MySlate's first (eyeLookIn 0.054 left, ``LeftEyeYaw`` -0.038) is the
  constant, not the slope (the sign before the fifty-fourth session was read from it).
"""


from __future__ import annotations

import base64
import dataclasses
import json
import re
import struct

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.cli.main import main
from facetransfer.export import ExportError, export_track
from facetransfer.export.livelink import app_rate, eye_angles, format_timecode, read_livelink
from test_export import _validate

RATES = (24000 / 1001, 24.0, 25.0, 30000 / 1001, 30.0, 48.0, 50.0, 60000 / 1001, 60.0)

#: The app's eye columns per unit of their curves (module notes: the three takes' slopes,
#: rounded): yaw per unit of In - Out (left eye) and of Out - In (right eye), pitch per unit of
#: Down - Up; signs as the app's.
APP_EYE_SLOPE = {"LeftEyeYaw": 0.60, "RightEyeYaw": 0.60, "LeftEyePitch": 0.57,
                 "RightEyePitch": 0.57}


def _unreal_seconds(codes) -> np.ndarray:
    """Each row's time as Unreal's Live Link Face importer reads it (module notes)."""
    parts = [c.split(":") for c in codes]
    rate = 60 if any(float(p[3]) > 30.0 for p in parts) else 30
    return np.array([int(h) * 3600 + int(m) * 60 + int(s) + float(f) / rate
                     for h, m, s, f in parts])


@pytest.mark.parametrize("fps", RATES)
def test_the_apps_labels_put_every_row_at_its_time_in_unreals_importer(fps):
    """``labels="app"``: the rows of a clip at any rate land where they belong in Unreal, one
    frame apart (clock time; the NTSC rates 29.97 and 59.94 counted on their nominal 30 and 60
    as the app counts them), from the start timecode; ``"clip"`` labels do only at 30 and 60
    (at 25 fps, 25 rows in each 5/6 s and a jump of 1/6 s: a time warp each second)."""
    n = 3 * round(fps) + 7
    step = 1.0 / (round(fps) if round(fps) == app_rate(fps) else fps)
    for start, at in ((None, 0.0), ("01:00:00:00", 3600.0), ("10:11:12:13", None)):
        t = _unreal_seconds([format_timecode(k, fps, start, labels="app") for k in range(n)])
        np.testing.assert_allclose(np.diff(t), step, atol=1e-3 / app_rate(fps) + 1e-9)
        if at is not None:
            assert t[0] == pytest.approx(at)
    clip = _unreal_seconds([format_timecode(k, fps) for k in range(n)])
    uniform = np.allclose(np.diff(clip), 1.0 / round(fps), atol=1e-6)
    assert uniform == (round(fps) in (30, 60))


def test_the_apps_labels_are_its_rates_and_its_format():
    """Frames of 30 a second up to 30 fps, of 60 above (the importer's guess is then right);
    every label ``HH:MM:SS:FF.mmm``; at 30 and 60 fps the labels are the clip's own."""
    assert [app_rate(f) for f in RATES] == [30, 30, 30, 30, 30, 60, 60, 60, 60]
    assert format_timecode(1, 25.0, labels="app") == "00:00:00:01.200"
    assert format_timecode(3, 25.0, "01:00:00:10", labels="app") == "01:00:00:15.600"
    assert format_timecode(1, 24.0, labels="app") == "00:00:00:01.250"
    assert format_timecode(1, 50.0, labels="app") == "00:00:00:01.200"
    assert format_timecode(1000, 24000 / 1001, "01:00:00:00", labels="app") == "01:00:41:21.250"
    for fps in (30.0, 60.0, 30000 / 1001):
        for k in (0, 1, 29, 1000):
            assert format_timecode(k, fps, "01:00:00:00", labels="app") \
                == format_timecode(k, fps, "01:00:00:00")
    pattern = re.compile(r"^\d\d:\d\d:\d\d:\d\d\.\d{3}$")
    for fps in RATES:
        assert all(pattern.match(format_timecode(k, fps, "23:59:59:00", labels="app"))
                   for k in range(200))
    with pytest.raises(ExportError, match="labels"):
        format_timecode(0, 25.0, labels="unreal")


def test_a_take_with_the_apps_labels_is_read_back_frame_for_frame(arkit_model,
                                                                    make_arkit_track, tmp_path):
    """The project's own reader places an app-labelled take's rows at ``k / fps``, as the
    clip's frames (``transfer --expression-from``, ``puppet``, ``view``), and by the plate's
    start timecode where it is on one."""
    from facetransfer.take import take_seconds

    track, a, _ = make_arkit_track(arkit_model, 40, fps=25.0)
    out = export_track(track, "livelink", tmp_path / "take.csv", labels="app")
    take = read_livelink(out)
    assert take.timecodes[:3] == ("00:00:00:00.000", "00:00:00:01.200", "00:00:00:02.400")
    np.testing.assert_allclose(take_seconds(take.timecodes), np.arange(40) / 25.0, atol=1e-9)
    np.testing.assert_allclose(take.activations, a, atol=1e-6)
    with pytest.raises(ExportError, match="only into livelink"):
        export_track(track, "json", tmp_path / "t.json", labels="app")
    from facetransfer import take as tk

    for fps, start in ((25.0, "00:00:02:00"), (24000 / 1001, "01:00:00:00"), (50.0, "10:00:00:00")):
        codes = [format_timecode(k, fps, start, labels="app") for k in range(300)]
        clock, first = tk._take_clock(codes, fps, start, "t")   # transfer's placement by timecode
        assert clock[0] == first
        np.testing.assert_allclose(clock - first, np.arange(300) / fps, atol=2e-5)


def test_export_take_rate_on_the_command_line(arkit_model, make_arkit_track, tmp_path, capsys):
    """The app's labels by default (``--take-rate app``: the same rows), said at 25 fps with
    the option for the clip's own count; ``--take-rate clip`` says that Unreal would misplace
    its rows; at 30 fps (or for a single row) nothing is said of it; for a glb, one line and
    exit status 2."""
    m = tmp_path / "m.npz"
    arkit_model.save(m)
    for fps, n in ((25.0, 30), (30.0, 30), (24.0, 1)):
        track, _, _ = make_arkit_track(arkit_model, n, fps=fps)
        track.save(tmp_path / f"t{fps:g}.npz")
    base = ["export", str(tmp_path / "t25.npz"), "--model", str(m), "--out"]
    assert main(base + [str(tmp_path / "d.csv")]) == 0
    out = capsys.readouterr().out
    assert "rows counted at 30 frames a second" in out and "--take-rate clip" in out
    assert main(base + [str(tmp_path / "a.csv"), "--take-rate", "app"]) == 0
    capsys.readouterr()
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "d.csv").read_bytes()
    assert read_livelink(tmp_path / "a.csv").timecodes[1] == "00:00:00:01.200"
    assert main(base + [str(tmp_path / "c.csv"), "--take-rate", "clip"]) == 0
    wrote = [x for x in capsys.readouterr().out.splitlines() if "Unreal" in x]
    assert len(wrote) == 1 and wrote[0].startswith(f"wrote {tmp_path / 'c.csv'}: 30 frames")
    assert "rows counted at the clip's 25 frames a second" in wrote[0]
    assert wrote[0].endswith("for Unreal, the default --take-rate app)")
    assert read_livelink(tmp_path / "c.csv").timecodes[1] == "00:00:00:01.000"
    for one in ("t30", "t24"):                     # 30 fps; a single row, at its time anyway
        assert main(["export", str(tmp_path / f"{one}.npz"), "--model", str(m), "--out",
                     str(tmp_path / f"{one}.csv")]) == 0
        assert "rows counted" not in capsys.readouterr().out
    assert main(base + [str(tmp_path / "a.glb"), "--take-rate", "app"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--take-rate app" in err and "glb" in err
    assert not (tmp_path / "a.glb").exists()


@pytest.mark.parametrize("curve, column, sign", [
    ("eyeLookInLeft", "LeftEyeYaw", 1), ("eyeLookOutLeft", "LeftEyeYaw", -1),
    ("eyeLookOutRight", "RightEyeYaw", 1), ("eyeLookInRight", "RightEyeYaw", -1),
    ("eyeLookDownLeft", "LeftEyePitch", 1), ("eyeLookUpLeft", "LeftEyePitch", -1),
    ("eyeLookDownRight", "RightEyePitch", 1), ("eyeLookUpRight", "RightEyePitch", -1)])
def test_eye_angles_turn_with_the_curves_as_the_apps_takes_do(curve, column, sign):
    """Each eyeLook* curve alone at 0.5 moves its eye's column as the app's takes move it
    (module notes): the app's sign (before, the yaw's was the other: an importer driving the
    eye bones from the columns turned them against the curves), the app's size within a
    factor 1.3 (ours: the tracker's 35 degrees a unit of In/Out, 28 of Up/Down), the other
    columns 0."""
    from facetransfer.export.livelink import POSE_COLUMNS

    a = np.zeros((1, 52))
    a[0, ARKIT_NAMES.index(curve)] = 0.5
    ours = dict(zip(POSE_COLUMNS[3:], eye_angles(a)[0]))
    want = sign * APP_EYE_SLOPE[column] * 0.5
    assert np.sign(ours[column]) == np.sign(want)
    assert abs(want) / 1.3 < abs(ours[column]) < abs(want) * 1.3
    assert all(v == 0 for name, v in ours.items() if name != column)


def _glb(path) -> tuple[dict, bytes, int]:
    """A glb's JSON chunk, its bytes and where its binary chunk's data starts."""
    b = path.read_bytes()
    n = struct.unpack("<I", b[12:16])[0]
    return json.loads(b[20:20 + n]), b, 20 + n + 8


def _accessor(g: dict, b: bytes, start: int, i: int) -> np.ndarray:
    """Float accessor ``i`` of a glb read by :func:`_glb`, ``(count, components)``."""
    acc = g["accessors"][i]
    view = g["bufferViews"][acc["bufferView"]]
    k = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc["type"]]
    at = start + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(b, np.float32, acc["count"] * k, at).reshape(-1, k)


def _glb_rotations(path) -> np.ndarray:
    """The head node's animated rotations ``(F, 4)`` (x, y, z, w) of a glb."""
    g, b, start = _glb(path)
    anim = g["animations"][0]
    ch = next(c for c in anim["channels"] if c["target"]["path"] == "rotation")
    return _accessor(g, b, start, anim["samplers"][ch["sampler"]]["output"])


def test_the_head_translation_is_from_the_frames_centre_as_the_renderer_has_it(arkit_model,
                                                                            tmp_path):
    """The model's origin where the renderer centres a frame (pixel k centred at k:
    ``((W - 1) / 2, (H - 1) / 2)``, :func:`facetransfer.render.look_at_weak_perspective`)
    exports no head translation, and 10 px right and 20 px up of it at 20 px a unit exports
    (0.5, 1.0, 0) units (glb: metres, x 0.01); before, half a pixel off (``W / 2``)."""
    from conftest import mean_person_track

    from facetransfer.export.common import head_translation

    track = mean_person_track(arkit_model, np.zeros((2, 52), np.float32), size=256,
                              scale=20.0)
    c = (256 - 1) / 2.0
    track = dataclasses.replace(track, translation=np.array([[c, c], [c + 10.0, c - 20.0]]))
    want = np.array([[0.0, 0.0, 0.0], [0.5, 1.0, 0.0]])
    np.testing.assert_allclose(head_translation(track), want, atol=1e-12)
    g, b, start = _glb(export_track(track, "glb", tmp_path / "t.glb", model=arkit_model))
    anim = g["animations"][0]
    ch = next(k for k in anim["channels"] if k["target"]["path"] == "translation")
    np.testing.assert_allclose(_accessor(g, b, start, anim["samplers"][ch["sampler"]]["output"]),
                               want * 0.01, atol=1e-7)


def test_glb_morph_targets_carry_the_shapes_normals(arkit_model, make_arkit_track, tmp_path):
    """Every morph target holds ``NORMAL`` deltas: the rest's normals plus a target's are its
    shape's own normals (read back from the file), and they matter: a full jawOpen turns many
    normals by over 10 degrees, which a player that keeps the rest's normals (three.js,
    glTFast, Godot) would shade as the closed face (before: ``POSITION`` deltas only)."""
    from facetransfer.export.gltf import _normals

    track, _, _ = make_arkit_track(arkit_model, 3)
    g, b, start = _glb(export_track(track, "glb", tmp_path / "f.glb", model=arkit_model))
    prim = g["meshes"][0]["primitives"][0]
    V = _accessor(g, b, start, prim["attributes"]["POSITION"])
    N = _accessor(g, b, start, prim["attributes"]["NORMAL"])
    faces = np.asarray(arkit_model.faces)
    assert len(prim["targets"]) == 52 and all("NORMAL" in t for t in prim["targets"])
    for name in ("mouthSmileRight", "eyeBlinkLeft", "jawOpen"):
        t = prim["targets"][ARKIT_NAMES.index(name)]
        D = _accessor(g, b, start, t["POSITION"])
        n = N + _accessor(g, b, start, t["NORMAL"])
        np.testing.assert_allclose(n, _normals(V + D, faces), atol=2e-6)
    turned = np.degrees(np.arccos(np.clip((N * n).sum(axis=1), -1, 1)))    # jawOpen's
    assert (turned > 10).sum() > 500
    issues = _validate(tmp_path / "f.glb")
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_a_head_turned_and_eyes_looking_to_the_subjects_left_in_every_export(arkit_model,
                                                                           tmp_path):
    """One truth (the head turned 20 degrees toward the subject's left, the image's right; both
    eyes looking to the subject's left) read the same in the take, the glb, the USD and the dial
    page: HeadYaw -20 degrees and both eyes' yaw negative, one sign for one way as the app has
    them (positive toward the subject's right: Unreal's ARKit code turns the head's and the
    eyes' rotations into angles by one rule; before the review, HeadYaw +20 beside the eyes'
    negative yaw); the nose toward +X (the subject's left) in the glb, the USD and the page."""
    from conftest import mean_person_track
    from scipy.spatial.transform import Rotation

    from facetransfer.export.viewer import viewer_page
    from facetransfer.render import rotation_from_euler

    a = np.zeros((3, 52), np.float32)
    a[:, ARKIT_NAMES.index("eyeLookOutLeft")] = 0.5
    a[:, ARKIT_NAMES.index("eyeLookInRight")] = 0.5
    R = rotation_from_euler(20.0, 0.0, 0.0)          # yaw > 0: toward the image's right
    track = mean_person_track(arkit_model, a, rotation=R)
    take = read_livelink(export_track(track, "livelink", tmp_path / "t.csv", model=arkit_model))
    np.testing.assert_allclose(take.pose[:, :3], [[-np.deg2rad(20.0), 0.0, 0.0]] * 3, atol=1e-7)
    assert np.all(take.pose[:, [3, 6]] < -0.2)       # LeftEyeYaw, RightEyeYaw
    nose = np.array([0.0, 0.0, 1.0])
    want = [np.sin(np.deg2rad(20.0)), 0.0, np.cos(np.deg2rad(20.0))]
    glb = _glb_rotations(export_track(track, "glb", tmp_path / "t.glb", model=arkit_model))
    np.testing.assert_allclose(Rotation.from_quat(glb).apply(nose), [want] * 3, atol=1e-6)
    page = viewer_page(arkit_model, track=track)
    q = np.frombuffer(base64.b64decode(
        re.search(r'"quaternions": "([^"]+)"', page).group(1)), np.float32).reshape(-1, 4)
    np.testing.assert_allclose(Rotation.from_quat(q).apply(nose), [want] * 3, atol=1e-6)
    pytest.importorskip("pxr")
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(export_track(track, "usd", tmp_path / "t.usda", model=arkit_model)))
    anim = next(UsdSkel.Animation(p) for p in stage.Traverse() if p.IsA(UsdSkel.Animation))
    r = anim.GetRotationsAttr().Get(1)[0]
    xyzw = [*r.GetImaginary(), r.GetReal()]
    np.testing.assert_allclose(Rotation.from_quat(xyzw).apply(nose), want, atol=1e-6)


def test_a_video_given_as_the_texture_is_said_as_such(arkit_model, make_arkit_track, tmp_path,
                                                      capsys):
    """``--texture clip.mp4`` (a video where an image is wanted): one line naming
    ``--texture-from``, exit status 2, nothing written (before: PIL's "cannot identify image
    file")."""
    m = tmp_path / "m.npz"
    arkit_model.save(m)
    track, _, _ = make_arkit_track(arkit_model, 4)
    track.save(tmp_path / "t.npz")
    (tmp_path / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    assert main(["export", str(tmp_path / "t.npz"), "--model", str(m), "--out",
                 str(tmp_path / "f.glb"), "--texture", str(tmp_path / "clip.mp4")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.endswith(f"--texture-from {tmp_path / 'clip.mp4'}")
    assert not (tmp_path / "f.glb").exists()


def test_a_clips_start_timecode_that_names_no_frame_is_said(arkit_model, make_arkit_track,
                                                             tmp_path, caplog):
    """A clip's recorded start timecode of frame 29 at 25 fps (no such frame: a camera or an
    editor's fault) is counted on from, frame 29 being a second and 4 frames, and said once
    (before: nothing said; a typed --timecode like it is refused)."""
    import dataclasses
    import logging

    from facetransfer.io.source_facts import SourceFacts

    track, _, _ = make_arkit_track(arkit_model, 3, fps=25.0)
    odd = dataclasses.replace(track, source_facts=SourceFacts(0, "01:00:00:29"))
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        out = export_track(odd, "livelink", tmp_path / "t.csv", labels="clip")
    assert read_livelink(out).timecodes[0] == "01:00:01:04.000"
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and said[0].startswith(
        "the clip's start timecode '01:00:00:29' names no frame at 25 fps"), said
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        export_track(dataclasses.replace(track, source_facts=SourceFacts(0, "01:00:00:24")),
                     "livelink", tmp_path / "u.csv")
    assert caplog.records == []


def test_a_takes_head_turns_the_apps_way_as_its_eyes_do(arkit_model, tmp_path):
    """A take as the app records it: ``HeadYaw`` +0.35 with the eyes looking in the same
    direction (``LeftEyeYaw``/``RightEyeYaw`` +0.3: toward the subject's right, as measured on
    the app's takes) and ``HeadRoll`` +0.2. ``take_track`` (what ``puppet``, ``view`` and
    ``export take.csv --out face.glb`` show) turns the nose toward the subject's right (the
    image's left, -x), with the eyes, and the face clockwise in the image (its +x axis, the
    subject's left, tipped down); pitch +0.1 looks down. Before the review, the head turned
    the other way from its eyes (nose toward +x) and counter-clockwise."""
    from facetransfer.export.livelink import HEADER
    from facetransfer.take import take_track

    values = dict.fromkeys(HEADER[2:], "0.0")
    values.update(HeadYaw="0.35", HeadPitch="0.1", HeadRoll="0.2", LeftEyeYaw="0.3",
                  RightEyeYaw="0.3")
    rows = [",".join(HEADER)] + [f"00:00:00:{k:02d}.000,61," + ",".join(values[n] for n in
                                                                      HEADER[2:])
                                 for k in range(3)]
    (tmp_path / "app.csv").write_text("\n".join(rows) + "\n")
    track = take_track(tmp_path / "app.csv", arkit_model, arkit_model.weight_mean("identity"))
    R = track.rotation[0]
    nose, left, up = R @ [0.0, 0.0, 1.0], R @ [1.0, 0.0, 0.0], R @ [0.0, 1.0, 0.0]
    assert nose[0] < -0.3                      # toward the subject's right: the image's left
    assert left[1] < -0.15                     # clockwise in the image: the +x side down
    assert up[2] > 0.05                        # the top of the head toward the camera: down
    gaze = track.info["eye_gaze"][0]           # (eye, (yaw + toward the subject's left, pitch))
    assert np.all(gaze[:, 0] < -0.25)          # the eyes toward the subject's right, the head too
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(Rotation.from_matrix(R).as_euler("YXZ"), [-0.35, 0.1, -0.2],
                               atol=1e-9)
