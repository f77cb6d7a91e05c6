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
