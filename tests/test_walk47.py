"""What a new user's walk through the README and the less-used commands found (forty-seventh
session, helper walk47)."""

from __future__ import annotations

import numpy as np

from facetransfer.cli.main import main


def test_a_take_or_a_table_given_as_a_mesh_names_the_mesh_formats(tmp_path, capsys):
    """``scan smooth take.csv`` said trimesh's "cannot read mesh take.csv: file_type 'csv'
    not supported"; a Live Link Face take (or an image) is now named as what it is, a file of
    another type by its extension, each with the mesh formats; a damaged mesh of a mesh
    format is still said as before."""
    import cv2

    take = tmp_path / "take.csv"
    take.write_text("Timecode,BlendShapeCount,EyeBlinkLeft\n00:00:00:00.000,1,0.5\n")
    table = tmp_path / "table.csv"
    table.write_text("a,b\n1,2\n")
    png = tmp_path / "face.ply"                   # an image under a mesh's name
    png.write_bytes(cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    meshes = "not a mesh: give one of .obj, .ply, .stl, .off, .glb"
    for path, what in ((take, "a Live Link Face take (CSV)"),
                       (table, "a file of type .csv"), (png, "a PNG image")):
        capsys.readouterr()
        assert main(["scan", "smooth", str(path), "--out", str(tmp_path / "s.obj")]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [
            f"facetransfer scan smooth: error: mesh file {path} is {what}, {meshes}"]
    broken = tmp_path / "broken.stl"
    broken.write_bytes(b"solid x\nfacet normal 0 0 1\n")
    assert main(["scan", "smooth", str(broken), "--out", str(tmp_path / "s.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"facetransfer scan smooth: error: mesh {broken} has no vertices", err
    assert not (tmp_path / "s.obj").exists()


def test_synth_video_performance_help_names_the_spec_keys(arkit_model, arkit_model_path,
                                                          tmp_path, capsys):
    """``synth-video --performance`` said only "performance spec (JSON, see
    facetransfer.synth)": its help now names every key of the spec (``n_frames``, not
    ``frames``) and the pose's, and its example is a spec that resolves; a wrong key is one
    line naming it and the known ones."""
    import json
    import re

    from facetransfer.cli.render import PERFORMANCE_HELP
    from facetransfer.synth import SPEC_KEYS, performance_from_spec

    from test_walk46 import _option_help

    text = _option_help(["synth-video"], "--performance")
    assert text == PERFORMANCE_HELP
    for key in {k for keys in SPEC_KEYS.values() for k in keys}:   # the parser's (polish47)
        assert re.search(rf"\b{key}\b", text), key
    example = json.loads(text[text.index("E.g. ") + 5:text.index("}}. ") + 2])
    perf = performance_from_spec(arkit_model, example)
    assert perf.n_frames == 50 and perf.size == (640, 480)
    spec = tmp_path / "p.json"
    spec.write_text('{"frames": 10}')
    capsys.readouterr()
    assert main(["synth-video", "--model", str(arkit_model_path), "--performance", str(spec),
                 "--out", str(tmp_path / "c.mp4")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"facetransfer synth-video: error: {spec}: unknown performance spec key(s) ['frames']; "
        f"known: {sorted(SPEC_KEYS['spec'])}"]
    assert not (tmp_path / "c.mp4").exists()


def test_a_stopped_track_run_is_pointed_to_the_tracks_own_frame_count(quick_model,
                                                                       quick_model_path,
                                                                       data_dir, tmp_path,
                                                                       capsys):
    """``track V --out T --overlay O --max-frames 5`` where T is an earlier run's track of 30
    frames suggested ``--from-track T --overlay O --max-frames 5``, which then failed (the
    track has 30); the hint now gives the track's own count (none for a track of the whole
    clip), and the command it gives draws the overlay; a track of another clip's size is only
    said to be there."""
    import dataclasses

    from conftest import still_track

    clip = str(data_dir / "video" / "face_2.mp4")          # 125 frames, 844x844
    t, o = tmp_path / "t.npz", tmp_path / "o.mp4"
    model = ["--model", str(quick_model_path)]

    def track_of(n, size=(844, 844)):
        still = still_track(quick_model, n, source=clip)
        return dataclasses.replace(still, frame_size=size, scale=np.full(n, 2.0),
                                   translation=np.tile((422.0, 422.0), (n, 1)))

    track_of(30).save(t)
    capsys.readouterr()
    assert main(["track", clip, *model, "--out", str(t), "--overlay", str(o),
                 "--max-frames", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    hint = f"--from-track {t} --overlay {o} --max-frames 30"
    assert err == [f"facetransfer track: error: output {t} exists (an earlier run's track of "
                   f"30 frames?): `{hint}` draws the overlay from it; for 5 frames, "
                   "--overwrite tracks again"], err
    assert main(["track", clip, *model, *hint.split(), "--no-progress"]) == 0
    assert o.is_file()
    o.unlink()
    track_of(125).save(t, overwrite=True)
    assert main(["track", clip, *model, "--out", str(t), "--overlay", str(o)]) == 2
    assert f"(an earlier run's track of 125 frames?): `--from-track {t} --overlay {o}` draws" \
        in capsys.readouterr().err
    track_of(30, (640, 480)).save(t, overwrite=True)
    assert main(["track", clip, *model, "--out", str(t), "--overlay", str(o)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"facetransfer track: error: output {t} exists, a track of another clip (30 frames of "
        "640x480; the video is 844x844): --overwrite replaces it"]
    assert not o.exists()
