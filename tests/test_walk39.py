"""What a new user's walk found (thirty-ninth session): a mesh folder that cannot be written,
a truncated video, a short or foreign performance, a take given as a performance, a source
track of another clip, option values out of range."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.cli.main import main  # noqa: E402
from test_transfer_cli import clips, run  # noqa: E402,F401 (fixture)


def test_a_meshes_folder_that_cannot_be_written_is_refused_before_any_work(tmp_path):
    from facetransfer.errors import OutputError
    from facetransfer.io.output_names import check_meshes_folder

    with pytest.raises(OutputError, match=r"--meshes /proc/mm"):
        check_meshes_folder("/proc/mm", overwrite=False)
    assert check_meshes_folder(tmp_path / "m", overwrite=False) == tmp_path / "m"
    assert not (tmp_path / "m").exists() and not list(tmp_path.iterdir())  # nothing left


def test_a_truncated_video_is_said_to_end_early(tmp_path, caplog):
    """A file cut after its first frames (its index at the front, so what is left decodes):
    its frames are read, and a warning says it ends before the frames its header counts."""
    import imageio_ffmpeg

    from facetransfer.io.video import read_video, write_video

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (64, 64, 3), np.uint8) for _ in range(60)]
    write_video(tmp_path / "a.mp4", frames, 25.0)
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-i",
                    str(tmp_path / "a.mp4"), "-c", "copy", "-movflags", "+faststart",
                    str(tmp_path / "f.mp4")], check=True)
    data = (tmp_path / "f.mp4").read_bytes()
    (tmp_path / "t.mp4").write_bytes(data[:len(data) // 3])
    with caplog.at_level(logging.WARNING):
        whole, _ = read_video(tmp_path / "f.mp4")
        assert not caplog.records
        cut, _ = read_video(tmp_path / "t.mp4")
    assert len(whole) == 60 and 3 <= len(cut) <= 40
    assert f"ends after frame {len(cut) - 1} of the 60 its header counts" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        read_video(tmp_path / "t.mp4", max_frames=2)    # fewer asked than it holds
    assert not caplog.records
    from facetransfer.io.video import iter_frames

    caplog.clear()
    (tmp_path / "t2.mp4").write_bytes(data[:len(data) // 3])
    with caplog.at_level(logging.WARNING):    # frame by frame, as a track reads (before: no
        streamed = list(iter_frames(tmp_path / "t2.mp4"))  # word, a shorter clip tracked)
        assert len(list(iter_frames(tmp_path / "t2.mp4", stop=2))) == 2
        read_video(tmp_path / "t2.mp4")                     # said once a file
    assert len(streamed) == len(cut)
    assert caplog.text.count(f"ends after frame {len(cut) - 1} of the 60") == 1
    from facetransfer.io.video_facts import fact_lines, video_facts

    facts = video_facts(tmp_path / "t.mp4")
    assert facts.n_frames == 60 and facts.stored_frames < 60
    assert f"the file holds {facts.stored_frames} of them (cut short?)" in fact_lines(facts)[1]
    whole = video_facts(tmp_path / "f.mp4")
    assert whole.stored_frames == 60 and "cut short" not in " ".join(fact_lines(whole))


def test_a_performance_shorter_than_the_target_is_refused_with_the_frames_to_give(
        clips, quick_model, tmp_path):
    from facetransfer import transfer_plan as tp
    from facetransfer.errors import RewriteError
    from facetransfer.track import Track
    from facetransfer.track.project import take_frames

    short = tmp_path / "short.npz"
    take_frames(Track.load(clips["target_track"]), np.arange(3)).save(short)
    with pytest.raises(RewriteError, match=r"performance .*short.npz has 3 frames, the target "
                                           r"video .*target.mp4 6: give --max-frames 3"):
        tp.plan_transfer(clips["target"], quick_model, target_track=clips["target_track"],
                         performance=short)
    plan = tp.plan_transfer(clips["target"], quick_model, target_track=clips["target_track"],
                            performance=short, max_frames=3)
    assert plan.n_frames == 3


def test_tracks_of_another_clip_are_said(clips, quick_model_path, tmp_path, capsys, caplog):
    """A source track or a performance made from another clip is named in a warning (as a
    target track is); a take given as --performance is pointed to --expression-from."""
    import shutil

    other = tmp_path / "other.mp4"
    shutil.copy(clips["source"], other)
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--expression-from", other, "--source-track",
                        clips["source_track"], "--model", quick_model_path, "--out",
                        tmp_path / "o.mp4", "--no-progress"], capsys)
    assert code == 0, err
    said = [r.getMessage() for r in caplog.records if "expression track" in r.getMessage()]
    assert len(said) == 1 and "was made from synthetic, not other.mp4" in said[0]
    take = tmp_path / "take.csv"
    take.write_text("Timecode,BlendShapeCount,EyeBlinkLeft\n00:00:00:00.000,1,0.5\n")
    code, _, err = run(["transfer", "--target", clips["target"], "--performance", take,
                        "--model", quick_model_path, "--out", tmp_path / "p.mp4"], capsys)
    assert code == 2 and err.strip().splitlines() == [
        f"facetransfer transfer: error: --performance {take} is a Live Link Face take: give "
        f"it as --expression-from {take} (a performance is a track file, TRACK.npz)"]


@pytest.mark.parametrize("option, value, said", [
    ("--smooth", "1e9", "argument --smooth: expected a number in [0, 1000], got '1e9'"),
    ("--points", "-5", "argument --points: expected an integer in [1, 1000000], got '-5'"),
    ("--passes", "0", "argument --passes: expected an integer in [1, 100], got '0'"),
    ("--keyframe", "x", "argument --keyframe: expected a number in [0, 1e+06], got 'x'")])
def test_tracking_options_out_of_range_name_the_option(option, value, said, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["track", str(tmp_path / "v.mp4"), "--out", str(tmp_path / "t.npz"), option,
              value])
    assert exc.value.code == 2
    assert said in capsys.readouterr().err


def test_a_crf_for_an_image_sequence_and_hevc_in_avi_are_refused(tmp_path):
    from facetransfer.errors import VideoError
    from facetransfer.io.video import VideoOptions, check_video_output

    with pytest.raises(VideoError, match=r"--crf sets a video's H.264/H.265 quality; an image "
                                         r"sequence's frames are written as .png files"):
        check_video_output(tmp_path / "f_%05d.png", VideoOptions(crf=10))
    assert check_video_output(tmp_path / "f_%05d.png", VideoOptions()).kind == "images"
    with pytest.raises(VideoError, match=r"H.265 goes in a .mp4, .mov or .mkv file, not .avi"):
        check_video_output(tmp_path / "v.avi", VideoOptions(codec="h265"))
    assert check_video_output(tmp_path / "v.avi", VideoOptions(codec="h264")).kind == "video"


@pytest.mark.parametrize("argv, said", [
    (["transfer", "--target", "t.mp4", "--expression-from", "s.mp4", "--output", "x.mp4"],
     "facetransfer transfer: error: unrecognized arguments: --output"),
    (["track", "v.mp4", "--ouut", "t.npz"], "facetransfer track: error: unrecognized arguments: "
     "--ouut")])
def test_a_misspelt_option_is_said_before_a_missing_required_one(argv, said, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and capsys.readouterr().err.startswith(said)


def test_values_that_look_like_options_are_not_taken_for_unknown_ones():
    from facetransfer.cli.main import build_parser, command_parser, unknown_options

    parser = build_parser()
    for argv in (["track", "v.mp4", "--crf", "-1", "--out", "t.npz", "-v"],
                 ["edit", "t.npz", "--scale", "jawOpen=-2", "--ou", "e.npz"],
                 ["-v", "probe", "a.mp4", "--json"], ["transfer", "--", "--odd"]):
        assert unknown_options(command_parser(parser, argv), argv) == [], argv
    argv = ["export", "t.npz", "--format", "glb", "--texure", "x.png", "--out", "t.glb"]
    assert unknown_options(command_parser(parser, argv), argv) == ["--texure"]
