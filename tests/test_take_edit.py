"""``facetransfer edit take.csv``: a Live Link Face take's ARKit curves edited, the rest of the
file kept (facetransfer.take.edit_take, facetransfer.cli.edit)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.cli.main import main
from facetransfer.export.livelink import read_livelink, write_livelink
from facetransfer.take import edit_take
from facetransfer.performance_edit import edit_activations, edit_track

EDITED = ("JawOpen", "MouthSmileLeft", "MouthSmileRight")


def _fields(path) -> list[list[str]]:
    return [line.split(",") for line in path.read_text().splitlines()]


def test_an_edited_take_changes_its_edited_curves_only(arkit_model, make_arkit_track, tmp_path,
                                                       capsys, caplog):
    """``edit take.csv --scale jawOpen=2 --add "smile*0.5@3-6" --out take2.csv``: the take's
    jawOpen doubled and both smiles raised over rows 3-6 with the ramps a track's edit has,
    clipped to [0, 1], as ``edit`` of the track the take was exported from edits them; every
    other field (timecodes, count, the other curves, head and eye rotations) and the header as
    they were. Before, the take was refused: "is not a track file"."""
    track, a, _ = make_arkit_track(arkit_model, 12, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv")
    out = tmp_path / "take2.csv"
    edits = ["--scale", "jawOpen=2", "--add", "smile*0.5@3-6", "--ramp", "2"]
    assert main(["edit", str(take), *edits, "--out", str(out)]) == 0, capsys.readouterr().err
    said = capsys.readouterr().out
    assert said.startswith(f"wrote {out}: 12 rows") and "JawOpen, MouthSmileLeft" in said
    before, after = _fields(take), _fields(out)
    assert after[0] == before[0] and len(after) == len(before)
    edited = [before[0].index(n) for n in EDITED]
    for row_before, row_after in zip(before[1:], after[1:]):
        kept = [k for k in range(len(row_before)) if k not in edited]
        assert [row_after[k] for k in kept] == [row_before[k] for k in kept]
    got = read_livelink(out).activations
    want = edit_activations(read_livelink(take).activations, scale=["jawOpen=2"],
                            add=["smile*0.5@3-6"], ramp=2)
    np.testing.assert_allclose(got, want, atol=1e-8)
    np.testing.assert_allclose(got, edit_track(track, arkit_model, scale="jawOpen=2",
                                               add="smile*0.5@3-6", ramp=2).blendshapes,
                               atol=1e-5)            # the track's edit, to the take's decimals
    j = ARKIT_NAMES.index("mouthSmileLeft")
    assert got[0, j] == read_livelink(take).activations[0, j]       # beyond the ramp: as it was
    assert got[2, j] > a[2, j] + 0.1 or got[2, j] == 1.0             # in the ramp, raised
    with caplog.at_level("WARNING", logger="facetransfer.take"):
        res = edit_take(take, tmp_path / "eyes.csv", scale="eyeLookInLeft=0.5")
    assert res.changed == ("EyeLookInLeft",)
    assert "eye rotation columns" in caplog.text


def test_a_take_of_another_tool_keeps_its_bytes(tmp_path, capsys):
    """A take as another tool or a spreadsheet saves it (a byte-order mark, CRLF lines,
    camelCase names, six decimals, no rotation or tongueOut column, a column of its own): the
    edited take is the same bytes but for the fields the edit changes (rows 2-4 of jawOpen,
    ``--ramp 0``). A curve the take has no column for is one line naming it."""
    names = [n for n in ARKIT_NAMES if n != "tongueOut"]
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 0.9, (8, len(names)))
    head = "Timecode,BlendShapeCount," + ",".join(names) + ",Note"
    rows = [f"01:00:00:{k:02d},{len(names)}," + ",".join(f"{v:.6f}" for v in a[k]) + ",take 3"
            for k in range(8)]
    take = tmp_path / "other.csv"
    take.write_bytes(("\ufeff" + "\r\n".join([head, *rows]) + "\r\n").encode("utf-8"))
    out = tmp_path / "other2.csv"
    assert main(["edit", str(take), "--add", "jawOpen*0.25@2-4", "--ramp", "0",
                 "--out", str(out)]) == 0, capsys.readouterr().err
    j = 2 + names.index("jawOpen")
    want = []
    for k, line in enumerate(rows):
        fields = line.split(",")
        if 2 <= k <= 4:
            fields[j] = f"{min(float(fields[j]) + 0.25, 1.0):.8f}"
        want.append(",".join(fields))
    assert out.read_bytes() == ("\ufeff" + "\r\n".join([head, *want]) + "\r\n").encode("utf-8")
    capsys.readouterr()
    assert main(["edit", str(take), "--add", "tongueOut@1-2", "--out",
                 str(tmp_path / "t.csv")]) == 2
    assert "has no tongueOut shape (no column TongueOut)" in capsys.readouterr().err


@pytest.mark.parametrize("extra, out, said", [
    (["--scale", "jawOpn=2"], "e.csv", "unknown expression 'jawOpn' (did you mean jawOpen?)"),
    (["--scale", "jawOpen=2", "--identity-dials", "width=1"], "e.csv",
     "is a Live Link Face take, which has no identity to dial"),
    (["--scale", "jawOpen=2"], "e.npz", "an edited take is written as .csv, not .npz"),
    (["--scale", "jawOpen=2"], "take.csv", "is also an input"),
    (["--scale", "jawOpen=2"], "there.csv", "exists; pass --overwrite"),
    (["--add", "jawOpen@3-40"], "e.csv", "outside the clip (0-11)"),
    (["--add", "mouthSmile*0.5@3-40"], "e.csv",   # the edit as typed (it lost its "*0.5")
     "--add mouthSmile*0.5@3-40: frames outside the clip (0-11)"),
])
def test_a_wrong_edit_of_a_take_is_one_line(arkit_model, make_arkit_track, tmp_path, capsys,
                                            extra, out, said):
    """Each mistake in an edit of a take is one line and exit status 2, nothing written: an
    unknown name (the closest one named), an identity to dial, a track's name for the output,
    the take itself, an output there already, rows beyond the take's."""
    track, _, _ = make_arkit_track(arkit_model, 12)
    take = write_livelink(track, tmp_path / "take.csv")
    (tmp_path / "there.csv").write_text("kept")
    assert main(["edit", str(take), *extra, "--out", str(tmp_path / out)]) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "e.csv").exists() and not (tmp_path / "e.npz").exists()
    assert (tmp_path / "there.csv").read_text() == "kept"
    assert main(["edit", str(take), "--scale", "jawOpen=2", "--out", str(tmp_path / "there.csv"),
                 "--overwrite"]) == 0
    assert (tmp_path / "there.csv").read_text().startswith("Timecode,BlendShapeCount,")


def test_a_tracks_edit_named_as_a_take_points_to_export(arkit_model, make_arkit_track, tmp_path,
                                                        capsys):
    """``edit TRACK.npz ... --out e.csv``: one line saying the edit is a track and how
    ``export`` makes a take of it (before: "a track is written as .npz")."""
    track, _, _ = make_arkit_track(arkit_model, 12)
    tp = tmp_path / "t.npz"
    track.save(tp)
    assert main(["edit", str(tp), "--scale", "jawOpen=2", "--out", str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err
    assert "`facetransfer export" in err and "turns it into a Live Link Face take" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "e.csv").exists()


def test_a_takes_edit_counts_frames_as_its_preview_does(arkit_model, make_arkit_track,
                                                         tmp_path, capsys):
    """A take whose rows skip frames (rows 4-6 of 12 dropped, as the app drops rows under
    load): ``edit --add jawOpen*0.3@8-9`` edits frames 8-9 of the take's timeline, the frames
    ``view take.csv`` and ``puppet take.csv`` number (and ``--neutral FRAME`` counts), not its
    rows 8-9 (frames 11-12, past the end: before, refused, "outside the clip (0-8)"), and
    ``--add ...@0-11`` covers the take; a row a few thousandths off its frame (the app's) is
    that frame's. A take whose timecodes repeat is one line, as the
    commands that play it say it (before, its rows were edited by their count)."""
    from facetransfer.take import take_track

    track, _, _ = make_arkit_track(arkit_model, 12, fps=30.0)
    full = write_livelink(track, tmp_path / "full.csv")
    lines = full.read_text().splitlines(keepends=True)
    take = tmp_path / "drop.csv"
    take.write_text("".join(lines[:5] + lines[8:]))      # rows of frames 4, 5, 6 dropped
    out = tmp_path / "drop2.csv"
    assert main(["edit", str(take), "--add", "jawOpen*0.3@8-9", "--ramp", "0",
                 "--out", str(out)]) == 0, capsys.readouterr().err
    ident = arkit_model.weight_mean(arkit_model.mode_index("identity"))
    shown = take_track(take, arkit_model, ident).blendshapes
    edited = take_track(out, arkit_model, ident).blendshapes
    assert len(shown) == len(edited) == 12
    j = ARKIT_NAMES.index("jawOpen")
    np.testing.assert_allclose(edited[8:10, j], np.minimum(shown[8:10, j] + 0.3, 1.0),
                               atol=1e-6)
    np.testing.assert_allclose(np.delete(edited, [8, 9], 0), np.delete(shown, [8, 9], 0),
                               atol=1e-6)
    assert main(["edit", str(take), "--add", "jawOpen*0.1@0-11", "--out",
                 str(tmp_path / "all.csv")]) == 0, capsys.readouterr().err
    jit = tmp_path / "jitter.csv"                        # the app's: rows a few ms off frames
    jit.write_text("".join([lines[0]] + [f"00:00:00:{k:02d}.{17 * k % 40:03d}" + line[15:]
                                         for k, line in enumerate(lines[1:])]))
    assert main(["edit", str(jit), "--add", "jawOpen*0.1@5-7", "--ramp", "0", "--out",
                 str(tmp_path / "jitter2.csv")]) == 0, capsys.readouterr().err
    d = read_livelink(tmp_path / "jitter2.csv").activations - read_livelink(jit).activations
    assert set(np.flatnonzero(d[:, j])) == {5, 6, 7}     # its rows of frames 5-7, exactly
    dup = tmp_path / "dup.csv"
    dup.write_text("".join(lines[:4] + lines[3:]))       # the row of frame 2 twice
    capsys.readouterr()
    assert main(["edit", str(dup), "--scale", "jawOpen=2", "--out",
                 str(tmp_path / "dup2.csv")]) == 2
    err = capsys.readouterr().err
    assert "timecodes repeat at row 4" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "dup2.csv").exists()


def test_a_name_as_the_takes_header_spells_it_is_taken(arkit_model, make_arkit_track, tmp_path,
                                                       capsys):
    """The take's column ``JawOpen`` (Unreal's Live Link curve name too) names ARKit's
    ``jawOpen``, and ``MouthSmile`` both smiles, whatever the case, in an edit of a take and of
    a track alike: the same output as in ARKit's spelling. Before, refused "did you mean
    jawOpen?". A name close to none is refused without a guess (before, ``xyz``: "did you mean
    eyeWideLeft?")."""
    from facetransfer.transfer import TransferError

    track, _, _ = make_arkit_track(arkit_model, 12)
    take = write_livelink(track, tmp_path / "take.csv")
    for names, out in ((["jawOpen=2", "mouthSmile*0.5@3-6"], "a.csv"),
                       (["JawOpen=2", "MouthSmile*0.5@3-6"], "b.csv"),
                       (["JAWOPEN=2", "Smile*0.5@3-6"], "c.csv")):
        assert main(["edit", str(take), "--scale", names[0], "--add", names[1],
                     "--out", str(tmp_path / out)]) == 0, capsys.readouterr().err
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes() \
        == (tmp_path / "c.csv").read_bytes() != take.read_bytes()
    want = edit_track(track, arkit_model, scale="jawOpen=2", add="mouthSmile*0.5@3-6")
    got = edit_track(track, arkit_model, scale="JawOpen=2", add="MouthSmile*0.5@3-6")
    for mode in want.weights:
        np.testing.assert_array_equal(got.weights[mode], want.weights[mode])
    with pytest.raises(TransferError, match="did you mean jawOpen") as err:
        edit_track(track, arkit_model, scale="jawOpn=2")
    with pytest.raises(TransferError, match="unknown expression 'xyz';") as err:
        edit_activations(read_livelink(take).activations, scale="xyz=2")
    assert "did you mean" not in str(err.value)


def test_a_takes_quoted_fields_keep_their_quotes(arkit_model, make_arkit_track, tmp_path,
                                                  capsys):
    """A take whose own column quotes its notes (``"take 3, good"``, a spreadsheet's ``""``,
    one note over two lines): the edited take is its bytes with the edited fields replaced.
    Before, an edited row's quotes were dropped (``take 3, good`` unquoted: a field more to a
    plain reader) and the two-line note ended the edit in an IndexError traceback."""
    track, _, _ = make_arkit_track(arkit_model, 8)
    lines = write_livelink(track, tmp_path / "plain.csv").read_text().splitlines()
    notes = ['"take 3, good"', '"a ""quoted"" word"', '"two\nlines"'] + ['""'] * 5
    take = tmp_path / "notes.csv"
    take.write_text("\n".join([lines[0] + ",Note"] + [f"{line},{note}" for line, note
                                                       in zip(lines[1:], notes)]) + "\n")
    out = tmp_path / "notes2.csv"
    assert main(["edit", str(take), "--scale", "jawOpen=0", "--out", str(out)]) == 0, \
        capsys.readouterr().err
    j = lines[0].split(",").index("JawOpen")
    want = []
    for line, note in zip(lines[1:], notes):
        fields = line.split(",")
        fields[j] = "0.00000000" if float(fields[j]) != 0 else fields[j]
        want.append(",".join(fields) + "," + note)
    assert out.read_text() == "\n".join([lines[0] + ",Note"] + want) + "\n"


def test_an_apps_value_past_one_outside_the_edit_keeps_its_bytes(tmp_path):
    """The app writes ARKit's overshoot as it comes (its take alex_rom_4: eyeLookIn up to
    1.053): ``edit take.csv --add jawOpen*0.2@2-5 --ramp 0`` of a take whose JawOpen is
    1.0533207655 in row 20 changes rows 2-5 only; row 20 keeps its field byte for byte, as
    every field the edit leaves as it was (before: the whole edited curve was clipped to 1, and
    row 20 was rewritten as 1.00000000). A value the edit moves is still clipped to 1."""
    from facetransfer.export.livelink import HEADER

    j = HEADER.index("JawOpen")
    rows = []
    for k in range(30):
        fields = [f"00:00:00:{k:02d}.000", "61"] + ["0.10000000"] * 61
        if k == 20:
            fields[j] = "1.0533207655"
        if k == 3:
            fields[j] = "0.95000000"
        rows.append(fields)
    take = tmp_path / "app.csv"
    take.write_text("\n".join(",".join(r) for r in [list(HEADER), *rows]) + "\n")
    res = edit_take(take, tmp_path / "e.csv", add="jawOpen*0.2@2-5", ramp=0)
    assert res.changed == ("JawOpen",)
    after = _fields(tmp_path / "e.csv")[1:]
    changed = [k for k in range(30) if after[k] != rows[k]]
    assert changed == [2, 3, 4, 5]
    assert [after[k][j] for k in changed] == ["0.30000000", "1.00000000", "0.30000000",
                                              "0.30000000"]
    assert after[20][j] == "1.0533207655"
