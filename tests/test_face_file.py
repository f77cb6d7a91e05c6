"""A face saved by the dial editor, made with the model (facetransfer.face_file; `render --face`,
`model synth --face`). The page's own file is checked in tests/test_view.py."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facetransfer.cli.main import main
from facetransfer.face_file import FaceFileError, face_rotation, face_weights, read_face


def _face(path, model, **changes):
    d = {"format": "facetransfer-face", "version": 1, "model": model.content_hash,
         "source": "m.npz", "frame": None,
         "identity": [float(v) for v in model.weight_mean("identity")],
         "identity_dials": {}, "shape_kind": "arkit", "shapes": {},
         "head": {"yaw": 0.0, "pitch": 0.0, "roll": 0.0}}
    d.update(changes)
    path.write_text(json.dumps(d), encoding="utf-8")
    return path


def test_the_pages_rotation_is_ry_rx_rz():
    """The page's angles (three.js Euler order YXZ): R = Ry(yaw) Rx(pitch) Rz(roll)."""
    from facetransfer.face_file import DialledFace

    f = DialledFace(None, "", np.zeros(1), {}, "arkit", {}, (20.0, -10.0, 5.0))
    y, p, r = np.deg2rad([20.0, -10.0, 5.0])
    R = (Rotation.from_rotvec([0, y, 0]) * Rotation.from_rotvec([p, 0, 0])
         * Rotation.from_rotvec([0, 0, r])).as_matrix()
    np.testing.assert_allclose(face_rotation(f), R, atol=1e-12)


def test_training_expression_sliders_add_their_offsets(quick_model, tmp_path):
    """A model without ARKit shapes: a slider at v adds v times its training expression's
    offset from the neutral, as the page draws it (exact: the mesh is linear in a mode)."""
    labs = [lab for lab in quick_model.labels[1] if lab != "neutral"][:2]
    face = read_face(_face(tmp_path / "f.json", quick_model, shape_kind="expression",
                           shapes={labs[0]: 0.5, labs[1]: 0.25}))
    w = face_weights(face, quick_model)
    rest = {"identity": quick_model.weight_mean("identity"),
            "expression": quick_model.training_weights("expression", "neutral")}
    neutral = quick_model.synthesize(rest)
    want = neutral + sum(v * (quick_model.synthesize({**rest, "expression": quick_model.
                                                      training_weights("expression", lab)})
                              - neutral) for lab, v in ((labs[0], 0.5), (labs[1], 0.25)))
    np.testing.assert_allclose(quick_model.synthesize(w), want, atol=1e-9)


def test_render_and_synth_make_the_saved_face(arkit_model, tmp_path, capsys):
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    face = _face(tmp_path / "f.json", arkit_model, shapes={"jawOpen": 1.0},
                 head={"yaw": 20.0, "pitch": 0.0, "roll": 0.0})
    assert main(["model", "synth", str(mp), "--face", str(face),
                 "--out", str(tmp_path / "f.obj")]) == 0
    # the mesh is the model's frame: its line says the file's head turn is left to render
    assert "without the face file's head turn (yaw 20, pitch 0, roll 0" in capsys.readouterr().out
    assert main(["model", "synth", str(mp), "--out", str(tmp_path / "n.obj")]) == 0
    import trimesh

    a = trimesh.load(tmp_path / "f.obj", process=False).vertices
    b = trimesh.load(tmp_path / "n.obj", process=False).vertices
    assert np.abs(a - b).max() > 0.5          # the jaw dropped (model units: cm)
    assert main(["render", str(mp), "--face", str(face), "--size", "160x120",
                 "--out", str(tmp_path / "f.png")]) == 0
    assert main(["render", str(mp), "--like", "expression=jawOpen", "--pose", "yaw=20",
                 "--size", "160x120", "--out", str(tmp_path / "g.png")]) == 0
    capsys.readouterr()
    from PIL import Image

    f, g = (np.asarray(Image.open(tmp_path / n)).astype(int) for n in ("f.png", "g.png"))
    assert np.abs(f - g).max() <= 1            # the same face, turned as the page turned it


def test_bad_face_files_are_one_line(arkit_model, quick_model, tmp_path, capsys):
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    (tmp_path / "text.json").write_text("not json")
    (tmp_path / "other.json").write_text(json.dumps({"format": "gltf"}))
    cases = [
        ("text.json", "is not a face file (not JSON"),
        ("other.json", 'expected "format": "facetransfer-face"'),
        (_face(tmp_path / "q.json", quick_model).name, "was dialled on another model"),
        (_face(tmp_path / "s.json", arkit_model, shapes={"jawOpenn": 1}).name,
         "unknown ARKit blendshape(s) jawOpenn"),
        (_face(tmp_path / "d.json", arkit_model, identity_dials={"widht": 1}).name,
         "unknown identity dial 'widht'"),
        (_face(tmp_path / "n.json", arkit_model, shapes={"jawOpen": "x"}).name,
         "'shapes' must map names to numbers"),
        ("missing.json", "does not exist"),
        ("m.npz", "m.npz is not a face file (it is a model file; the dial editor's Save face"),
        # edited by hand beyond what the page makes: refused, not drawn torn apart
        (_face(tmp_path / "b.json", arkit_model, shapes={"jawOpen": 5}).name,
         "shape jawOpen=5 is outside 0 to 1"),
        (_face(tmp_path / "w.json", arkit_model, identity_dials={"width": 50}).name,
         "identity dial width=50 is outside -5 to 5"),
        (_face(tmp_path / "h.json", arkit_model, head={"yaw": 0, "tilt": 9}).name,
         "'head' has 'tilt'; expected 'yaw', 'pitch' and 'roll'"),
        # JSON integers beyond a float's range (numpy's isfinite raised TypeError: a traceback)
        (_face(tmp_path / "i.json", arkit_model, identity_dials={"width": 10 ** 400}).name,
         "'identity_dials' must map names to numbers"),
        (_face(tmp_path / "j.json", arkit_model, identity=[10 ** 400] * 3).name,
         "'identity' must be a list of numbers"),
    ]
    for name, msg in cases:
        assert main(["model", "synth", str(mp), "--face", str(tmp_path / name),
                     "--out", str(tmp_path / "o.obj")]) == 2, name
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    good = _face(tmp_path / "g.json", arkit_model)
    assert main(["model", "synth", str(mp), "--face", str(good), "--like", "expression=jawOpen",
                 "--out", str(tmp_path / "o.obj")]) == 2
    assert "not --face and --like" in capsys.readouterr().err
    assert main(["render", str(mp), "--face", str(good), "--pose", "yaw=3",
                 "--out", str(tmp_path / "o.png")]) == 2
    assert "the --face file gives the head's rotation" in capsys.readouterr().err
    # the face file is an input: never written over, whatever its name
    for cmd, name in ((["model", "synth"], "face.obj"), (["render"], "face.png")):
        named = tmp_path / name
        named.write_bytes(good.read_bytes())
        assert main(cmd + [str(mp), "--face", str(named), "--out", str(named),
                           "--overwrite"]) == 2
        assert "is also an input" in capsys.readouterr().err
        assert named.read_bytes() == good.read_bytes()
    with pytest.raises(FaceFileError, match="version 2"):
        read_face(_face(tmp_path / "v.json", arkit_model, version=2))


def test_a_trilinear_models_visemes_have_sliders_and_are_kept(data_dir, tmp_path):
    """The paper's trilinear model: the page has a slider per viseme as per expression (named
    ``viseme:LABEL``), and a saved face's visemes become the viseme mode's weights (before:
    no viseme slider, the visemes held at their mean)."""
    import re

    from facetransfer.export.viewer import viewer_page
    from facetransfer.model import build_model

    from test_transfer_viseme import _trilinear_dataset

    tri = build_model(_trilinear_dataset(data_dir), {"identity": 4, "expression": 4,
                                                     "viseme": 5})
    names = json.loads(re.search(r'<script id="ft-data" type="application/json">(.*?)</script>',
                                 viewer_page(tri), re.S).group(1))["target_names"]
    assert {"smile", "browsup", "viseme:AA", "viseme:OO", "viseme:rest"} <= set(names)
    face = read_face(_face(tmp_path / "t.json", tri, shape_kind="expression",
                           shapes={"smile": 0.5, "viseme:AA": 1.0}))
    w = face_weights(face, tri)
    rest = {m: tri.weight_mean(m) for m in ("identity", "viseme")}
    rest["expression"] = tri.training_weights("expression", "neutral")
    np.testing.assert_allclose(w["expression"], rest["expression"] + 0.5 * (
        tri.training_weights("expression", "smile") - rest["expression"]), atol=1e-12)
    np.testing.assert_allclose(w["viseme"], tri.training_weights("viseme", "AA"), atol=1e-12)
    for bad in ("viseme:ZZ", "identity:id01", "pose:AA"):
        with pytest.raises(FaceFileError, match=f"unknown shape '{bad}'"):
            face_weights(read_face(_face(tmp_path / "b.json", tri, shape_kind="expression",
                                         shapes={bad: 1.0})), tri)


def test_an_identity_beyond_the_models_is_refused_as_identity_weights_are(arkit_model,
                                                                          tmp_path, capsys):
    """A hand-edited identity (all zeros, a one-hot, a far-off value) is refused naming the
    file, as the same weights given to ``transfer --identity-weights`` are
    (:func:`facetransfer.transfer.check_identity_weights`); before, ``render --face`` drew the
    zero identity blown past its frame. A training identity's row is taken."""
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    U = arkit_model.factors[arkit_model.mode_index("identity")]
    r = U.shape[1]
    for name, w in (("z.json", np.zeros(r)), ("o.json", np.eye(r)[0]),
                    ("f.json", U[1] + 40 * U.std(0))):
        path = _face(tmp_path / name, arkit_model, identity=[float(v) for v in w])
        assert main(["render", str(mp), "--face", str(path), "--size", "160x120",
                     "--out", str(tmp_path / "o.png")]) == 2, name
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err
        assert f"{path}: its identity: component " in err
        assert "standard deviations from the training identities'" in err
        assert "the dial editor saves" in err
        assert not (tmp_path / "o.png").exists()
        with pytest.raises(FaceFileError, match="standard deviations"):
            face_weights(read_face(path), arkit_model)
    row = _face(tmp_path / "t.json", arkit_model, identity=[float(v) for v in U[2]])
    np.testing.assert_array_equal(face_weights(read_face(row), arkit_model)["identity"], U[2])


def test_a_face_of_another_model_names_the_positional_model_argument(
        arkit_model, quick_model, tmp_path, capsys, monkeypatch):
    """``model synth`` and ``render`` take their model as the MODEL argument, not ``--model``:
    a face dialled on the default model, given another, was told to "leave out --model" (an
    option these commands do not have); a face of another version's kept default model was
    told to "give --model P". Now both name MODEL."""
    import facetransfer.default_model as dm
    import facetransfer.model_hint as mh
    from facetransfer.cli.model import positional_hint

    mp = tmp_path / "q.npz"
    quick_model.save(mp)
    face = _face(tmp_path / "f.json", arkit_model)
    monkeypatch.setattr(mh, "current_default_hash", lambda: arkit_model.content_hash)
    for argv in (["model", "synth", str(mp), "--face", str(face), "--out", str(tmp_path / "o.obj")],
                 ["render", str(mp), "--face", str(face), "--out", str(tmp_path / "o.png")]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.endswith("(made with the default model: leave out MODEL)"), err
        assert "--model" not in err and len(err.splitlines()) == 1
    kept = tmp_path / "cache" / "ict-arkit-default-v1-0123.npz"
    monkeypatch.setattr(mh, "current_default_hash", lambda: None)
    monkeypatch.setattr(dm, "kept_model", lambda h: kept if h == arkit_model.content_hash else None)
    assert main(["model", "synth", str(mp), "--face", str(face),
                 "--out", str(tmp_path / "o.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"kept at {kept}: give {kept} as MODEL)"), err
    # an option's command keeps the option's name
    assert positional_hint("x (made with the default model: leave out --model)", "--model") \
        .endswith("leave out --model)")
