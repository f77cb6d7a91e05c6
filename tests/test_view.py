"""The browser dial editor: a self-contained page, drawn in headless Chromium."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.export.viewer import THREE_VERSION, viewer_page, write_viewer

CANVAS = (slice(20, 680), slice(20, 540))  # rows, columns of the 3D view in a 900x700 window
BACKGROUND = np.array([244, 242, 239])


def _chromium() -> str:
    exe = os.environ.get("FACETRANSFER_CHROMIUM") or shutil.which("chromium") \
        or shutil.which("chromium-browser")
    if not exe:
        pytest.skip("chromium is not installed (apt-get install -y chromium)")
    return exe


def _shot(page: Path, fragment: str, tmp_path: Path) -> np.ndarray:
    from PIL import Image

    exe = _chromium()
    out = tmp_path / f"shot_{abs(hash(fragment))}.png"
    with tempfile.TemporaryDirectory() as profile:
        res = subprocess.run(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", f"--user-data-dir={profile}", "--window-size=900,700",
             f"--screenshot={out}", f"{page.resolve().as_uri()}#{fragment}"],
            capture_output=True, text=True, timeout=180)
    assert out.is_file(), res.stderr[-2000:]
    return np.asarray(Image.open(out).convert("RGB"))[CANVAS].astype(np.int16)


@pytest.fixture(scope="module")
def pages(arkit_model, make_arkit_track, tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    mp, tp = d / "m.npz", d / "t.npz"
    arkit_model.save(mp)
    track, a, _ = make_arkit_track(arkit_model, 8)
    track.save(tp)
    return (write_viewer(mp, d / "model.html"), write_viewer(tp, d / "track.html",
                                                             model=arkit_model), track, a)


def test_vendored_three_is_the_pinned_build():
    import hashlib
    from importlib import resources

    from facetransfer.export.viewer import THREE_SHA256

    root = resources.files("facetransfer.data").joinpath("vendor/three")
    assert hashlib.sha256(root.joinpath("three.min.js").read_bytes()).hexdigest() == THREE_SHA256
    assert "MIT License" in root.joinpath("LICENSE").read_text()
    assert THREE_VERSION in root.joinpath("README.md").read_text()


def test_page_is_self_contained(pages):
    page = pages[0].read_text()
    assert f"three.js {THREE_VERSION}" in page and "THREE.WebGLRenderer" in page
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", page)
    assert '"target_names"' in page and "eye_spacing" in page and "jawOpen" in page
    t = pages[1].read_text()
    assert '"n_frames": 8' in t and 'id="play"' in t


@pytest.mark.slow
def test_face_is_drawn_and_dials_move_it(pages, tmp_path):
    model_page, track_page, _, _ = pages
    base = _shot(model_page, "", tmp_path)
    face = np.abs(base - BACKGROUND).sum(axis=2) > 30
    assert face.mean() > 0.15, "no face drawn"  # the face fills a good part of the view
    for frag in ("jawOpen=1", "width=3&yaw=20"):
        moved = _shot(model_page, frag, tmp_path)
        changed = (np.abs(moved - base).sum(axis=2) > 30).mean()
        assert changed > 0.005, frag  # moving a slider changes the pixels
    f0 = _shot(track_page, "frame=0", tmp_path)
    f5 = _shot(track_page, "frame=5", tmp_path)
    assert (np.abs(f5 - f0).sum(axis=2) > 30).mean() > 0.005  # the timeline drives the face


def _saved_face(page: Path, fragment: str, out: Path) -> Path:
    """What the page's Save face would download, read from its text box in headless Chromium's
    DOM after the page applied ``fragment``."""
    import html

    exe = _chromium()
    with tempfile.TemporaryDirectory() as profile:
        res = subprocess.run(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-background-networking", "--disable-component-update",
             f"--user-data-dir={profile}", "--dump-dom", f"{page.resolve().as_uri()}#{fragment}"],
            capture_output=True, text=True, timeout=180)
    m = re.search(r'<textarea id="face"[^>]*>(.*?)</textarea>', res.stdout, re.S)
    assert m and m.group(1).strip(), res.stderr[-2000:]
    out.write_text(html.unescape(m.group(1)), encoding="utf-8")
    return out


@pytest.mark.slow
def test_a_plates_page_takes_and_saves_the_plates_frame_numbers(arkit_model, pages, tmp_path):
    """The page of a plate's track (numbered from 1001) takes ``#frame=1004`` as the plate's
    frame 1004 (its row 3), shows 1004 and saves ``"frame": 1004`` with row 3's face (before:
    1004 was past the 8 rows, read as the last one, and the saved frame was the row); an older
    page's address, which kept the row (``#frame=3``), still names that frame, as no frame of
    the plate is numbered so low. A video's track keeps its rows (``test_a_saved_face...``)."""
    from facetransfer.arkit import weights_to_activations
    from facetransfer.face_file import face_weights, read_face
    from facetransfer.io.source_facts import SourceFacts

    _, _, track, a = pages
    plate = dataclasses.replace(track, source="plate/sh.####.png",
                                source_facts=SourceFacts(1001, None))
    plate.save(tmp_path / "plate.npz")
    page = write_viewer(tmp_path / "plate.npz", tmp_path / "plate.html", model=arkit_model)
    for address in ("frame=1004", "frame=3"):
        assert '<span id="frameno">1004</span>' in _dom(page, address), address
        face = read_face(_saved_face(page, address, tmp_path / "p.json"))
        assert face.frame == 1004, address
        w = face_weights(face, arkit_model)["expression"]
        np.testing.assert_allclose(weights_to_activations(arkit_model, w[None])[0], a[3],
                                   atol=2e-6)
    face = read_face(_saved_face(page, "frame=1008", tmp_path / "last.json"))
    assert face.frame == 1008          # the plate's last frame, row 7


@pytest.mark.slow
def test_an_older_address_below_a_long_plates_first_number_is_its_row(arkit_model, pages,
                                                                       tmp_path):
    """An older page's address kept the row: one below the plate's first number is none of the
    plate's frames, so it is read as that row even where the plate has more frames than its
    first number (``frame=500`` of a plate of 1500 frames from 1001; here ``frame=3`` of 8
    rows numbered from 5: row 3, frame 8; before, read as frame 3, before the plate's first,
    and the page showed its first frame). A number that is both a row and one of the plate's
    (``frame=6``) stays the plate's: row 1."""
    from facetransfer.arkit import weights_to_activations
    from facetransfer.face_file import face_weights, read_face
    from facetransfer.io.source_facts import SourceFacts

    _, _, track, a = pages
    plate = dataclasses.replace(track, source="plate/sh.####.png",
                                source_facts=SourceFacts(5, None))
    plate.save(tmp_path / "plate.npz")
    page = write_viewer(tmp_path / "plate.npz", tmp_path / "plate.html", model=arkit_model)
    for address, number, row in (("frame=3", 8, 3), ("frame=0", 5, 0), ("frame=6", 6, 1)):
        assert f'<span id="frameno">{number}</span>' in _dom(page, address), address
        face = read_face(_saved_face(page, address, tmp_path / "p.json"))
        assert face.frame == number, address
        w = face_weights(face, arkit_model)["expression"]
        np.testing.assert_allclose(weights_to_activations(arkit_model, w[None])[0], a[row],
                                   atol=2e-6)


@pytest.mark.slow
def test_a_saved_face_is_the_pages_face(arkit_model, pages, tmp_path):
    """The dial editor's Save face holds what the page shows: a track's frame (its activations
    and head rotation to float32's precision) with a dial moved, and a model's sliders; the
    model's weights made of it (facetransfer.face_file) are that frame's identity moved by the
    dial and its expression."""
    from facetransfer.arkit import weights_to_activations
    from facetransfer.dials import learn_dials
    from facetransfer.face_file import face_rotation, face_weights, read_face

    model_page, track_page, track, a = pages
    face = read_face(_saved_face(track_page, "frame=3&width=1.5", tmp_path / "t.json"))
    assert face.frame == 3 and face.identity_dials == {"width": 1.5}
    w = face_weights(face, arkit_model)
    want = learn_dials(arkit_model).apply(track.weights["identity"][3], {"width": 1.5})
    np.testing.assert_allclose(w["identity"], want, atol=1e-12)
    np.testing.assert_allclose(weights_to_activations(arkit_model, w["expression"][None])[0],
                               a[3], atol=2e-6)
    np.testing.assert_allclose(face_rotation(face), track.rotation[3], atol=1e-5)
    face = read_face(_saved_face(model_page, "jawOpen=0.5&yaw=20&pitch=-10&roll=5",
                                 tmp_path / "m.json"))
    assert face.frame is None and face.shapes == {"jawOpen": 0.5} and not face.identity_dials
    np.testing.assert_allclose(face.head, (20, -10, 5), atol=1e-9)
    np.testing.assert_allclose(face_weights(face, arkit_model)["identity"],
                               arkit_model.weight_mean("identity"), atol=1e-12)
    # a track cut to another person at frame 4: a frame after the cut keeps that person
    other = arkit_model.training_weights("identity", arkit_model.labels[0][3])
    assert np.abs(other - track.weights["identity"][0]).max() > 0.1
    ident = track.weights["identity"].copy()
    ident[4:] = other
    cut = dataclasses.replace(track, weights={**track.weights, "identity": ident},
                              shot_starts=(4,))
    tp = tmp_path / "cut.npz"
    cut.save(tp)
    page = write_viewer(tp, tmp_path / "cut.html", model=arkit_model)
    for frame, want in ((6, other), (2, track.weights["identity"][0])):
        face = read_face(_saved_face(page, f"frame={frame}", tmp_path / f"c{frame}.json"))
        np.testing.assert_array_equal(face.identity, want)


@pytest.mark.slow
def test_an_address_outside_the_sliders_is_held_to_them(pages, tmp_path):
    """A typed or shared address beyond a slider's range draws (and saves) the slider's end, and
    a value that is no number leaves its slider alone (before: jawOpen=5 drew and saved a face
    torn five times open, jawOpen=abc a face of NaN that vanished); the head keeps its angle."""
    from facetransfer.face_file import read_face

    face = read_face(_saved_face(pages[0], "jawOpen=5&width=-9&yaw=60&mouthClose=abc",
                                 tmp_path / "f.json"))
    assert face.shapes == {"jawOpen": 1} and face.identity_dials == {"width": -3}
    assert face.head == (60, 0, 0)


def test_view_cli_and_bad_input(arkit_model, pages, tmp_path, capsys):
    _, _, track, _ = pages
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    tp = tmp_path / "t.npz"
    track.save(tp)
    assert main(["view", str(tp), "--model", str(mp), "--out", str(tmp_path / "p.html")]) == 0
    assert "wrote" in capsys.readouterr().out
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "zero.npz").write_bytes(b"")
    with open(tmp_path / "array.npz", "wb") as fh:    # an .npy named .npz: was a TypeError
        np.save(fh, np.zeros(3))
    for src, msg in ((tmp_path / "none.npz", "does not exist"),
                     (tmp_path / "array.npz", "it is an .npy array, not an .npz archive"),
                     (tmp_path / "zero.npz", f"model or track file {tmp_path / 'zero.npz'} is "
                                             "empty"),
                     (tmp_path / "junk.npz", "neither a model nor a track")):
        assert main(["view", str(src), "--out", str(tmp_path / "q.html")]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert main(["view", str(mp), "--out", str(tmp_path / "p.html")]) == 2  # exists
    assert "--overwrite" in capsys.readouterr().err
    page = viewer_page(arkit_model)
    assert '"n_frames": 0' in page
    # no input: the default model's page (before: "model or track file default does not
    # exist" to `view default`, and the input was required); --model's model, given one
    assert main(["view", "--model", str(mp), "--out", str(tmp_path / "d.html")]) == 0
    assert (tmp_path / "d.html").read_text(encoding="utf-8").count('"n_frames": 0') == 1
    assert main(["view", "--model", str(mp), "--neutral", "3",
                 "--out", str(tmp_path / "e.html")]) == 2
    assert "--neutral is for a track" in capsys.readouterr().err


def test_view_neutral_pose(arkit_model, pages, tmp_path, capsys):
    """``--neutral 2``: the page's activations are the calibrated ones (decoded from the page);
    a model has no neutral frame."""
    import base64
    import re

    from facetransfer.export.neutral import calibrated

    _, _, track, a = pages
    mp, tp = tmp_path / "m.npz", tmp_path / "t.npz"
    arkit_model.save(mp)
    track.save(tp)
    out = tmp_path / "n.html"
    assert main(["view", str(tp), "--model", str(mp), "--out", str(out), "--neutral", "2"]) == 0
    capsys.readouterr()
    blobs = [np.frombuffer(base64.b64decode(b), np.float32)
             for b in re.findall(r'"activations": "([A-Za-z0-9+/=]+)"', out.read_text())]
    assert len(blobs) == 1
    np.testing.assert_allclose(blobs[0].reshape(a.shape), calibrated(a, 2), atol=1e-6)
    assert main(["view", str(mp), "--out", str(tmp_path / "m.html"), "--neutral", "auto"]) == 2
    assert "--neutral is for a track" in capsys.readouterr().err


def test_page_of_a_model_without_arkit_shapes(quick_model):
    import json

    page = viewer_page(quick_model, title="quick")
    data = json.loads(re.search(r'<script id="ft-data" type="application/json">(.*?)</script>',
                                page, re.S).group(1))
    shapes = data["target_names"][:data["n_shapes"]]
    assert shapes == [lab for lab in quick_model.labels[1] if lab != "neutral"]
    assert data["shape_title"].startswith("expression") and data["n_frames"] == 0
    # int16 offsets with one scale per target reproduce the model's shape offsets
    q = np.frombuffer(__import__("base64").b64decode(data["targets"]), np.int16)
    n = quick_model.n_vertices
    first = q[: n * 3].reshape(n, 3) * data["target_scales"][0]
    from facetransfer.dials import neutral_weights

    rest = neutral_weights(quick_model)
    w = quick_model.weight_mean(0)
    want = quick_model.synthesize({**rest, "identity": w, "expression": quick_model
                                   .training_weights(1, shapes[0])}) \
        - quick_model.synthesize({**rest, "identity": w})
    np.testing.assert_allclose(first, want, atol=2 * data["target_scales"][0])


def test_view_of_a_live_link_face_take(arkit_model, pages, tmp_path, capsys):
    """``view take.csv``: the page's timeline holds the take's activations (decoded from the
    page) and as many frames."""
    import base64

    from facetransfer.export.livelink import write_livelink

    _, _, track, a = pages
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    take = write_livelink(track, tmp_path / "take.csv")
    out = tmp_path / "take.html"
    assert main(["view", str(take), "--model", str(mp), "--out", str(out)]) == 0
    capsys.readouterr()
    page = out.read_text()
    blobs = [np.frombuffer(base64.b64decode(b), np.float32)
             for b in re.findall(r'"activations": "([A-Za-z0-9+/=]+)"', page)]
    assert len(blobs) == 1 and f'"n_frames": {len(a)}' in page
    np.testing.assert_allclose(blobs[0].reshape(a.shape), a, atol=1e-6)


def test_view_of_a_take_measured_from_a_neutral_row_shows_what_export_writes(
        arkit_model, pages, tmp_path, capsys):
    """``view take.csv --neutral 0`` (or ``auto``): the page's activations are those ``export
    take.csv --neutral`` writes (its json read back), not the take's as recorded. Before, view
    refused it ("--neutral is for a track") while export took it. A frame outside the take is
    one line naming the take (before, "the track has frames 0 to ...")."""
    import base64

    from facetransfer.export.livelink import write_livelink
    from facetransfer.export.mpjson import read_mediapipe_json

    _, _, track, a = pages
    mp = tmp_path / "m.npz"
    arkit_model.save(mp)
    take = write_livelink(track, tmp_path / "take.csv")
    for neutral in ("0", "auto"):
        page, js = tmp_path / f"n{neutral}.html", tmp_path / f"n{neutral}.json"
        assert main(["view", str(take), "--model", str(mp), "--out", str(page),
                     "--neutral", neutral]) == 0, capsys.readouterr().err
        assert main(["export", str(take), "--model", str(mp), "--out", str(js),
                     "--neutral", neutral]) == 0, capsys.readouterr().err
        capsys.readouterr()
        blobs = re.findall(r'"activations": "([A-Za-z0-9+/=]+)"', page.read_text())
        shown = np.frombuffer(base64.b64decode(blobs[0]), np.float32).reshape(a.shape)
        np.testing.assert_allclose(shown, read_mediapipe_json(js), atol=1e-6)
        assert np.abs(shown - a).max() > 0.01      # measured from the row, not as recorded
    assert main(["view", str(take), "--model", str(mp), "--out", str(tmp_path / "x.html"),
                 "--neutral", str(len(a))]) == 2
    assert f"the take {take} has frames 0 to {len(a) - 1}" in capsys.readouterr().err


def test_a_track_of_a_model_without_arkit_activations_is_refused_naming_it(quick_model,
                                                                             tmp_path, capsys):
    """The track page's timeline plays ARKit activations: a track of another kind of model is
    refused naming the track file and why (before: no file, no reason)."""
    from conftest import still_track

    still_track(quick_model, 3, source="clip.mp4").save(tmp_path / "t.npz")
    quick_model.save(tmp_path / "m.npz")
    assert main(["view", str(tmp_path / "t.npz"), "--model", str(tmp_path / "m.npz"),
                 "--out", str(tmp_path / "p.html")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"facetransfer view: error: track {tmp_path / 't.npz'}: its timeline plays "
                   "ARKit activations, and the model's expressions are not ARKit blendshapes "
                   "(the default model's, ict-arkit, are) (`view` of the model itself has a "
                   "slider per training expression)"], err
    assert not (tmp_path / "p.html").exists()


def test_a_track_of_another_model_is_named_when_its_model_is_missing(quick_model, data_dir,
                                                                     tmp_path, capsys):
    """`view T.npz` (and `export`) without --model, of a track made with another model than the
    default one: the line names the track (before: "the track was not made with ...") and both
    content hashes, the track's and the default model's here (a track of another build of the
    default model is told from one of another model)."""
    from conftest import still_track

    from facetransfer.default_model import load_default_model

    tp = tmp_path / "other.npz"
    still_track(quick_model, 3).save(tp)
    assert main(["view", str(tp), "--out", str(tmp_path / "p.html")]) == 2
    err = capsys.readouterr().err.strip().splitlines()   # (on a fresh machine, the default
    # model's one-line note of its first build comes first)
    here = load_default_model().content_hash[:12]
    assert err[-1] == (f"facetransfer view: error: track {tp} was not made with the default "
                       f"model (ict-arkit) here (model hash {quick_model.content_hash[:12]}, "
                       f"this one's {here}); pass the model it was tracked with (--model M.npz)")
    assert not [line for line in err[:-1] if "error" in line or "Traceback" in line]


def _page_data(page: str) -> dict:
    import json

    return json.loads(re.search(r'<script id="ft-data" type="application/json">(.*?)</script>',
                                page, re.S).group(1))


def _eye_numbers_check(arkit_model, data: dict, activations: np.ndarray) -> None:
    """The page's eye numbers (export.viewer.eye_data) give activation_gaze's angles for
    ``activations`` (F, 52) and eye_model's eyeballs for the page's neutral."""
    from facetransfer.track.gaze import activation_gaze, eye_model

    E = data["eyes"]
    got = np.zeros((len(activations), 2, 2))
    for j, e, yaw, pitch in E["gaze"]:
        got[:, e] += activations[:, [j]] * [yaw, pitch]
    np.testing.assert_allclose(got, activation_gaze(activations), atol=1e-12)
    n = arkit_model.n_vertices
    V = np.frombuffer(__import__("base64").b64decode(data["positions"]), np.float32)
    V = V.reshape(-1, 3).astype(np.float64)
    want = eye_model(V[:n][np.asarray(arkit_model.landmarks)])
    for e, (o, i) in enumerate(E["corners"]):
        w = np.linalg.norm(V[o] - V[i])
        np.testing.assert_allclose((V[o] + V[i]) / 2 + w * np.array(E["offset"][e]),
                                   want.centre[e], atol=1e-5)
        np.testing.assert_allclose(w * E["ratio"][e], want.radius[e], atol=1e-6)


def test_the_pages_eye_numbers_are_eye_model_and_activation_gaze(arkit_model, pages):
    """The numbers the page turns and places its eyeballs by: per eye, the sum of each
    eyeLook* slider times its handed yaw and pitch is activation_gaze's angles (random
    activation sets, and each eyeLook* alone), and the eyeball from the corners is eye_model's;
    a model without landmarks has no eyeballs."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.gaze import GAZE_NAMES

    data = _page_data(pages[0].read_text())
    a = np.random.default_rng(3).uniform(0, 1, (6, 52))
    unit = np.zeros((8, 52))
    unit[range(8), [ARKIT_NAMES.index(nm) for nm in GAZE_NAMES]] = 1.0
    _eye_numbers_check(arkit_model, data, np.concatenate([a, unit]))
    assert sorted(ARKIT_NAMES[j] for j, *_ in data["eyes"]["gaze"]) == sorted(GAZE_NAMES)
    no_lm = dataclasses.replace(arkit_model, landmarks=None)
    assert _page_data(viewer_page(no_lm))["eyes"] is None


def _dom(page: Path, fragment: str) -> str:
    """The page's DOM after it applied ``fragment``, in a 900x700 window (as :func:`_shot`)."""
    exe = _chromium()
    with tempfile.TemporaryDirectory() as profile:
        res = subprocess.run(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-background-networking", "--disable-component-update",
             f"--user-data-dir={profile}", "--window-size=900,700", "--dump-dom",
             f"{page.resolve().as_uri()}#{fragment}"], capture_output=True, text=True, timeout=180)
    assert 'data-eyes="' in res.stdout, res.stderr[-2000:]
    return res.stdout


def _drawn_eyes(page: Path, fragment: str) -> list:
    """What the page drew of its eyeballs (its ``#gaze`` element's ``data-eyes``)."""
    import html
    import json

    return json.loads(html.unescape(re.search(r'data-eyes="([^"]*)"', _dom(page, fragment))
                                    .group(1)))


@pytest.mark.slow
def test_the_drawn_eyeballs_are_eye_model_turned_by_activation_gaze(arkit_model, pages):
    """In the page (headless Chromium) the eyeballs point where gaze_direction of
    activation_gaze's angles points, for sliders set in the address, and sit where eye_model
    puts them for the identity the dials show (the eye_spacing and width dials move the eye
    corners: the eyeballs follow); on the track's page they follow its eyeLook* curves."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.dials import learn_dials
    from facetransfer.export.viewer import view_rig
    from facetransfer.track.gaze import activation_gaze, eye_model, gaze_direction

    model_page, track_page, track, acts = pages
    dials = learn_dials(arkit_model)
    neutral, _, _, _, dial_off = view_rig(arkit_model, arkit_model.weight_mean("identity"), dials)
    lm = np.asarray(arkit_model.landmarks)
    for sliders, dial in (({"eyeLookOutLeft": 0.8, "eyeLookUpLeft": 0.3, "eyeLookInRight": 0.5,
                            "eyeLookDownRight": 0.6}, {}),
                          ({"eyeLookInLeft": 1.0, "eyeLookOutRight": 0.25, "eyeLookUpRight": 1.0},
                           {"eye_spacing": 2.5, "width": -1.5})):
        a = np.zeros((1, 52))
        for k, v in sliders.items():
            a[0, ARKIT_NAMES.index(k)] = v
        frag = "&".join(f"{k}={v}" for k, v in {**sliders, **dial}.items())
        drawn = _drawn_eyes(model_page, frag)
        V = neutral + sum(v * dial_off[dials.names.index(k)] for k, v in dial.items())
        want = eye_model(V[lm])
        dirs = gaze_direction(activation_gaze(a))[0]
        for e in range(2):
            np.testing.assert_allclose(drawn[e]["direction"], dirs[e], atol=2e-6)
            np.testing.assert_allclose(drawn[e]["centre"], want.centre[e], atol=2e-3)
            np.testing.assert_allclose(drawn[e]["radius"], want.radius[e], atol=2e-3)
    drawn = _drawn_eyes(track_page, "frame=5")
    dirs = gaze_direction(activation_gaze(acts[5:6].astype(np.float64)))[0]
    np.testing.assert_allclose([d["direction"] for d in drawn], dirs, atol=2e-6)


#: The 3-D view's size in :func:`_shot`'s 900x700 window (the panel takes 351 pixels).
VIEW = (549, 700)


def _eye_box(eye: dict) -> tuple[slice, slice]:
    """Rows and columns of a :func:`_shot` about where the page drew an eye's iris at rest
    (``iris_at``, ``radius_at`` of :func:`_drawn_eyes`: view heights from the view's centre)."""
    x = VIEW[0] / 2 + eye["iris_at"][0] * VIEW[1] - CANVAS[1].start
    y = VIEW[1] / 2 + eye["iris_at"][1] * VIEW[1] - CANVAS[0].start
    r = eye["radius_at"] * VIEW[1]
    return (slice(int(y - 0.6 * r), int(y + 0.6 * r) + 1),
            slice(int(x - 1.3 * r), int(x + 1.3 * r) + 1))


def _eye_pixels(shot: np.ndarray, eye: dict) -> np.ndarray:
    """The pixels (k, 3) of :func:`_eye_box`."""
    return shot[_eye_box(eye)].reshape(-1, 3)


def _sclera(px: np.ndarray) -> np.ndarray:
    """Light, nearly grey pixels that are not the page's background."""
    return (px.min(1) > 150) & (np.ptp(px, 1) < 40) & (np.abs(px - BACKGROUND).sum(1) > 12)


def _iris(px: np.ndarray) -> np.ndarray:
    """The lit iris's brown (puppet_face.PALETTE's, G / R 0.65, B / R 0.39, its rim's 0.62,
    0.38: green well below red, unlike the skin's 0.83 and 0.73; greener than the dark red
    inside's G / R 0.35, and its blends with the lids' skin at a blink, whose B / R is over
    0.45 where G / R is over 0.58: (56, 31, 26) is one) or the pupil's black (darker than the
    inside's sum of 81)."""
    s = px.sum(1)
    r = np.maximum(px[:, 0], 1)
    g, b = px[:, 1] / r, px[:, 2] / r
    return ((g > 0.58) & (g < 0.76) & (b < 0.45) & (px[:, 0] > 50)) | (s < 40)


@pytest.mark.slow
def test_the_eyes_show_an_eyeball_that_the_lids_hide_and_the_gaze_turns(pages, tmp_path):
    """The eye holes show an eyeball (before: the page's background): no background, and sclera
    and iris or pupil pixels in each eye with the eyes open; none of either with eyeBlinkLeft =
    eyeBlinkRight = 1; with eyeLookOutLeft = 1 the subject's left iris (image right for a
    frontal face) sits right of where it is at rest, with eyeLookInLeft = 1 left of it, the
    right eye's unmoved."""
    model_page = pages[0]
    eyes = _drawn_eyes(model_page, "")
    open_ = _shot(model_page, "", tmp_path)
    for eye in eyes:
        px = _eye_pixels(open_, eye)
        assert not (np.abs(px - BACKGROUND).sum(1) <= 12).any()  # before: hundreds
        assert _sclera(px).sum() > 20 and _iris(px).sum() > 20, (_sclera(px).sum(),
                                                                   _iris(px).sum())
    shut = _shot(model_page, "eyeBlinkLeft=1&eyeBlinkRight=1", tmp_path)
    for eye in eyes:
        px = _eye_pixels(shut, eye)
        assert not _sclera(px).any() and not _iris(px).any()

    def iris_x(frag):
        shot = _shot(model_page, frag, tmp_path)
        out = []
        for eye in eyes:
            rows, cols = _eye_box(eye)
            box = shot[rows, cols]
            xs = np.nonzero(_iris(box.reshape(-1, 3)).reshape(box.shape[:2]))[1]
            out.append(xs.mean() + cols.start)
        return np.array(out)

    rest, out, inward = iris_x(""), iris_x("eyeLookOutLeft=1"), iris_x("eyeLookInLeft=1")
    r = eyes[1]["radius_at"] * VIEW[1]
    assert out[1] > rest[1] + 0.2 * r and inward[1] < rest[1] - 0.2 * r, (rest, out, inward)
    assert abs(out[0] - rest[0]) < 1 and abs(inward[0] - rest[0]) < 1


@pytest.mark.slow
def test_the_open_mouth_shows_a_dark_inside_not_the_page(pages, tmp_path):
    """With jawOpen = 1 the mouth's gap is dark (before: the page's background showed through
    it, a hole in the face): no patch of background lies inside the face, and the shot has
    many more of the inside's dark red pixels than with the jaw shut."""
    from scipy import ndimage

    model_page = pages[0]
    shut, gaping = _shot(model_page, "", tmp_path), _shot(model_page, "jawOpen=1", tmp_path)
    for shot in (shut, gaping):
        labels, n = ndimage.label(np.abs(shot - BACKGROUND).sum(axis=2) < 12)
        edge = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0],
                                             labels[:, -1]])))
        holes = [k for k in range(1, n + 1) if k not in edge and (labels == k).sum() > 4]
        assert not holes, [(labels == k).sum() for k in holes]

    def dark(im):   # the inside's dark reds (puppet_face.PALETTE's cavity, darker to the back)
        r = im[..., 0]
        return int(((r > 1.8 * im[..., 1]) & (r > 1.8 * im[..., 2]) & (r > 15)).sum())

    assert dark(gaping) - dark(shut) > 1000, (dark(gaping), dark(shut))


@pytest.mark.slow
def test_a_takes_page_turns_the_eyes_by_its_recorded_angles(arkit_model, tmp_path, capsys):
    """``view take.csv`` of a take with its own eye rotation columns (20° to the subject's left,
    0.1 rad down; eyeLook* 0): the page hands track_gaze's angles (what the puppet turns its
    eyes by) and draws the eyeballs that way at a frame (before: ahead, by the eyeLook* 0);
    an eyeLook* slider moved from the frame's value adds its activation_gaze angles."""
    import base64

    from test_puppet_eyes import RECORDED, _take_with_eye_columns

    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.puppet_face import track_gaze
    from facetransfer.take import take_track
    from facetransfer.track.gaze import activation_gaze, gaze_direction

    take = _take_with_eye_columns(arkit_model, tmp_path / "take.csv", **RECORDED)
    mp, out = tmp_path / "m.npz", tmp_path / "take.html"
    arkit_model.save(mp)
    assert main(["view", str(take), "--model", str(mp), "--out", str(out)]) == 0
    capsys.readouterr()
    want = track_gaze(take_track(take, arkit_model, arkit_model.weight_mean("identity")))
    handed = np.frombuffer(base64.b64decode(_page_data(out.read_text())["frame_gaze"]),
                           np.float32).reshape(want.shape)
    np.testing.assert_allclose(handed, want, atol=1e-7)
    drawn = _drawn_eyes(out, "frame=1")
    np.testing.assert_allclose([d["direction"] for d in drawn], gaze_direction(want[1]),
                               atol=2e-6)
    a = np.zeros((1, 52))
    a[0, ARKIT_NAMES.index("eyeLookUpRight")] = 0.5
    drawn = _drawn_eyes(out, "frame=1&eyeLookUpRight=0.5")
    np.testing.assert_allclose([d["direction"] for d in drawn],
                               gaze_direction(want[1] + activation_gaze(a)[0]), atol=2e-6)


def test_the_pages_iris_and_pupil_are_the_puppets(pages):
    """The page's iris and pupil (half-angles about the eyeball's centre) are the puppet's
    discs (puppet_face.IRIS_RADIUS, PUPIL_RADIUS on gaze.EYE_RADIUS's ball): one size written
    once (before: 34 and 11 degrees typed again beside the puppet's 0.59 and 0.2 cm)."""
    from facetransfer.puppet_face import IRIS_RADIUS, PUPIL_RADIUS
    from facetransfer.track.gaze import EYE_RADIUS

    E = _page_data(pages[0].read_text())["eyes"]
    for got, r in ((E["iris_angle"], IRIS_RADIUS), (E["pupil_angle"], PUPIL_RADIUS)):
        assert got == pytest.approx(np.degrees(np.arcsin(r / EYE_RADIUS)), abs=1e-9)


@pytest.mark.slow
def test_the_pages_lid_shade_is_the_puppets(arkit_model, pages):
    """The page's shade of each eyeball as its lids close is the puppet's
    (puppet_face.lid_light of the face the page shows), at a half blink, eyeBlink 0.8 and a
    blink: one rule for both (LID_PAIRS, LID_SHADE in puppet_face); and from the face's own
    shut gap (puppet_face.shut_gaps_at_blink, the exports' rule) where its lids stay apart at
    eyeBlink 1."""
    from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
    from facetransfer.puppet_face import lid_light

    for blink in (0.5, 0.8, 1.0):
        drawn = _drawn_eyes(pages[0], f"eyeBlinkLeft={blink}&eyeBlinkRight={blink}")
        a = np.zeros((1, 52), np.float32)
        a[0, [ARKIT_NAMES.index("eyeBlinkLeft"), ARKIT_NAMES.index("eyeBlinkRight")]] = blink
        w = {**arkit_model.default_weights(), "expression": activations_to_weights(arkit_model,
                                                                                   a)[0]}
        V = arkit_model.synthesize(w)
        want = lid_light(V[np.asarray(arkit_model.landmarks)])
        np.testing.assert_allclose([d["lit"] for d in drawn], want, atol=2e-3)
    # pageeyes56: the track's page shows identity 1, whose lids stop 0.098 eye widths apart at
    # eyeBlink 1: its shade ramps from that face's own shut gap (puppet_face.face_shut_gaps, the
    # exports' gltf_eyes.shut_gaps), as the puppet's, to 1e-6 (before: from 0.08, the shut eye
    # drawn at 6-9 % light)
    from facetransfer.puppet_face import LID_SHADE, face_shut_gaps

    _, track_page, track, acts = pages
    shut = face_shut_gaps(arkit_model, track.weights_at(0))
    assert np.all(shut > LID_SHADE[0])
    for blink in (0.9, 1.0):
        drawn = _drawn_eyes(track_page, f"frame=0&eyeBlinkLeft={blink}&eyeBlinkRight={blink}")
        a = np.array(acts[:1], np.float32)
        a[0, [ARKIT_NAMES.index("eyeBlinkLeft"), ARKIT_NAMES.index("eyeBlinkRight")]] = blink
        V = arkit_model.synthesize({**track.weights_at(0),
                                    "expression": activations_to_weights(arkit_model, a)[0]})
        np.testing.assert_allclose([d["shut_gap"] for d in drawn], shut, rtol=0, atol=1e-6)
        want = lid_light(V[np.asarray(arkit_model.landmarks)], shut)
        np.testing.assert_allclose([d["lit"] for d in drawn], want, atol=2e-3)
        assert [d["visible"] for d in drawn] == list(want > 0)


def _painted(page: Path) -> dict:
    """The colours the page painted with (its body's ``data-palette``: sRGB ``#rrggbb``)."""
    import html
    import json

    return json.loads(html.unescape(re.search(r'data-palette="([^"]*)"', _dom(page, ""))
                                    .group(1)))


@pytest.mark.slow
def test_the_page_paints_with_the_puppets_palette(pages):
    """One palette for the two previews (puppet_face.PALETTE): the page's skin, its eyeballs'
    canvas (pupil, iris, the iris's rim, sclera: each a row's mean, the iris's fibres lighter
    and darker about its colour), the mouth's inside at the lips and at the back (and the
    head's inside) and the upper teeth are the puppet's. Before, the page had colours of its
    own: a #d9b59f skin, a sienna iris, a #f1ede4 sclera, a #2a1212 inside, no teeth."""
    from facetransfer.puppet_face import CAVITY_BACK, PALETTE

    drawn = _painted(pages[0])
    want = {**PALETTE, "cavity_back": np.asarray(PALETTE["cavity"]) * CAVITY_BACK}
    for name, rgb in want.items():
        got = [int(drawn[name][i:i + 2], 16) for i in (1, 3, 5)]
        # the limbus: the canvas's last iris row, a row short of the gradient's end
        np.testing.assert_allclose(got, rgb, atol=8 if name == "limbus" else 1.5, err_msg=name)


def _colours(img: np.ndarray, eye_boxes, *, page: bool) -> dict:
    """The lit sclera (the mean of the brightest quarter of its pixels), the iris's, the
    mouth's inside's and the skin's median colours of a frontal face ``img``, the eyes' in
    ``eye_boxes``: pixels told by the hues of the palette's colours, the same rule for both
    previews; the upper teeth: pixels within 12 of the palette's (unlit, both)."""
    from facetransfer.puppet_face import PALETTE

    px = img.reshape(-1, 3).astype(np.float64)
    r = np.maximum(px[:, 0], 1.0)
    g, b = px[:, 1] / r, px[:, 2] / r
    in_eyes = np.zeros(img.shape[:2], bool)
    for rows, cols in eye_boxes:
        in_eyes[rows, cols] = True
    in_eyes = in_eyes.ravel()
    bg = (np.abs(px - BACKGROUND).sum(1) <= 12) if page else np.zeros(len(px), bool)
    sclera = in_eyes & ~bg & (px.min(1) > 100) & (np.ptp(px, 1) < 40)
    bright = sclera & (px.sum(1) >= np.percentile(px[sclera].sum(1), 75))
    iris = in_eyes & (g > 0.5) & (g < 0.76) & (b < 0.55) & (px[:, 0] > 50)
    cavity = (px[:, 0] > 1.8 * px[:, 1]) & (px[:, 0] > 1.8 * px[:, 2]) & (px[:, 0] > 15)
    skin = (np.abs(g - 0.83) < 0.04) & (np.abs(b - 0.73) < 0.04) & (px[:, 0] > 40)
    teeth = ~in_eyes & (np.abs(px - PALETTE["teeth"]).max(1) <= 12)
    return {"sclera": px[bright].mean(0), "iris": np.median(px[iris], 0),
            "teeth": px[teeth].mean(0) if teeth.sum() > 20 else np.zeros(3),
            "cavity": np.median(px[cavity], 0) if cavity.sum() > 50 else np.zeros(3),
            "skin": np.median(px[skin], 0),
            "n": (int(iris.sum()), int(cavity.sum()), int(teeth.sum()))}


@pytest.mark.slow
def test_the_page_and_the_puppet_show_the_same_colours(arkit_model, pages, tmp_path):
    """The two previews side by side, the tests' ARKit model's mean person facing the camera
    with its mouth open (jawOpen = 0.7): the puppet's frame and the page's shot show the same
    lit sclera, iris, mouth inside, skin and upper teeth (each within 18 of 255 a channel; each
    preview lit its own way: the puppet from the camera, the page by its key and sky lights,
    matched on the skin). Before, the page's iris was a sienna (G / R 0.51 against the puppet's
    0.69) and its mouth's inside a near black (42, 18, 18) against the puppet's red (96, 34,
    32) darkening to half, and it drew no teeth."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.puppet_video import puppet_frames

    from conftest import mean_person_track

    a = np.zeros((1, 52), np.float32)
    a[0, ARKIT_NAMES.index("jawOpen")] = 0.7
    track = mean_person_track(arkit_model, a, size=320, scale=14.0)
    img = next(puppet_frames(track, arkit_model, arkit_model.weight_mean("identity")))
    V = arkit_model.synthesize(track.weights_at(0))
    lm = np.asarray(arkit_model.landmarks)
    boxes = []
    for eye in (range(36, 42), range(42, 48)):
        P = track.camera(0).project(V[lm[list(eye)]])
        (x0, y0), (x1, y1) = np.floor(P.min(0)) - 2, np.ceil(P.max(0)) + 2
        boxes.append((slice(int(y0), int(y1) + 1), slice(int(x0), int(x1) + 1)))
    puppet = _colours(img, boxes, page=False)
    shot = _shot(pages[0], "jawOpen=0.7", tmp_path)
    page = _colours(shot, [_eye_box(e) for e in _drawn_eyes(pages[0], "jawOpen=0.7")],
                    page=True)
    print({k: (np.round(puppet[k]).tolist(), np.round(page[k]).tolist()) for k in puppet})
    for k in ("sclera", "iris", "cavity", "skin", "teeth"):
        np.testing.assert_allclose(page[k], puppet[k], atol=18, err_msg=k)


def _teeth_pixels(img: np.ndarray, eye_boxes) -> int:
    """How many pixels of ``img`` outside ``eye_boxes`` and 3 pixels or more from the page's
    background (the head's outline blends the skin into it) are the palette's teeth (within
    12)."""
    from scipy import ndimage

    from facetransfer.puppet_face import PALETTE

    near = np.abs(img.astype(np.int16) - PALETTE["teeth"]).max(axis=2) <= 12
    near &= ~ndimage.binary_dilation(np.abs(img - BACKGROUND).sum(axis=2) <= 12, iterations=3)
    for rows, cols in eye_boxes:
        near[rows, cols] = False
    return int(near.sum())


@pytest.mark.slow
def test_a_shut_mouth_shows_no_teeth_on_the_page_as_on_the_puppet(arkit_model, pages, tmp_path):
    """The lips at rest (and barely parted, jawOpen = 0.03) are shut for the puppet
    (puppet_face.SHUT: the lips' line, no cavity, no teeth) and for the page: no pixel of the
    palette's teeth between them. Before, the page painted the teeth band on the mouth's
    inside whatever the lips' gap, so every face at rest showed a cream line between its lips
    (before the palette's teeth, the cavity's red-brown line); with the jaw open (0.3) both
    show the teeth."""
    from facetransfer.puppet_video import puppet_frames

    from conftest import jaw_open_track

    track = jaw_open_track(arkit_model, [0.0, 0.03, 0.3], size=320, scale=14.0)
    puppet = list(puppet_frames(track, arkit_model, arkit_model.weight_mean("identity")))
    lm = np.asarray(arkit_model.landmarks)
    counts = []
    for i, frag in enumerate(("", "jawOpen=0.03", "jawOpen=0.3")):
        P = track.camera(i).project(arkit_model.synthesize(track.weights_at(i))[lm[36:48]])
        top = int(np.ceil(P[:, 1].max())) + 3   # the puppet's eyes: every row above this
        shot = _shot(pages[0], frag, tmp_path)
        boxes = [_eye_box(e) for e in _drawn_eyes(pages[0], frag)]
        counts.append((_teeth_pixels(shot, boxes),
                       _teeth_pixels(puppet[i], [(slice(0, top), slice(None))])))
    assert counts[0] == counts[1] == (0, 0) and min(counts[2]) > 20, counts
