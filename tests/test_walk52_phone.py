"""Phone footage (helper walk52): files as phones write them, and what the commands make of
them (BENCHMARKS.md, "Fifty-second session (helper walk52)")."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")

from facetransfer.io.video import encode_video  # noqa: E402

FF = imageio_ffmpeg.get_ffmpeg_exe()


def _run(*args):
    subprocess.run([FF, "-hide_banner", "-loglevel", "error", "-y", *args], check=True)


def _clip_sound_first(tmp_path, lead=0.5):
    """A 3-second 30 fps clip whose picture starts ``lead`` seconds after its sound (as
    ``-itsoffset`` writes it: an edit list), a beep in the sound at 1.0 s of the file."""
    pic, snd, out = tmp_path / "pic.mp4", tmp_path / "snd.m4a", tmp_path / "phone.mp4"
    _run("-f", "lavfi", "-i", "testsrc=size=64x64:rate=30:duration=3", "-c:v", "libx264",
         "-pix_fmt", "yuv420p", str(pic))
    _run("-f", "lavfi", "-i", "aevalsrc=sin(2*PI*440*t)*between(t\\,1\\,1.2):s=48000:d=3.5",
         "-c:a", "aac", str(snd))
    _run("-itsoffset", str(lead), "-i", str(pic), "-i", str(snd), "-map", "0:v", "-map", "1:a",
         "-c", "copy", str(out))
    return out


def _beep_at(path) -> float:
    """Seconds into ``path``'s decoded sound where the beep starts."""
    pcm = subprocess.run([FF, "-hide_banner", "-loglevel", "error", "-i", str(path), "-map",
                          "0:a:0", "-ac", "1", "-ar", "8000", "-f", "f32le", "-"],
                         capture_output=True, check=True).stdout
    sound = np.frombuffer(pcm, np.float32)
    return float(np.argmax(np.abs(sound) > 0.3)) / 8000


@pytest.mark.parametrize("known", [True, False])
def test_the_sound_of_a_clip_whose_picture_starts_late_stays_in_step(tmp_path, known):
    """The beep is 0.5 s after the picture's first frame in the clip, and so in the output
    (in one pass with the frames, or muxed after them); before, the sound was taken from the
    file's start: the beep at 1.0 s, half a second late."""
    clip = _clip_sound_first(tmp_path)
    assert abs(_beep_at(clip) - 1.0) < 0.03       # the file's own timeline
    frames = np.full((60, 64, 64, 3), 128, np.uint8)
    res = encode_video(tmp_path / "out.mp4", frames if known else iter(frames), 30,
                       audio_from=clip)
    assert res.audio and res.n_frames == 60
    assert abs(_beep_at(res.path) - 0.5) < 0.03


def test_probe_says_the_sound_starts_before_the_picture(tmp_path):
    """``probe`` names the lead (before, it said ``audio aac`` alone); a clip whose sound and
    picture start together says nothing more."""
    from facetransfer.io.video_facts import fact_lines, video_facts
    facts = video_facts(_clip_sound_first(tmp_path))
    assert abs(facts.picture_start - 0.5) < 0.01
    assert "audio aac (starting 0.50 s before the picture" in "\n".join(fact_lines(facts))
    both = tmp_path / "both.mp4"
    _run("-i", str(tmp_path / "pic.mp4"), "-i", str(tmp_path / "snd.m4a"), "-map", "0:v",
         "-map", "1:a", "-c", "copy", str(both))
    facts = video_facts(both)
    assert facts.picture_start == 0.0 and "before the picture" not in "\n".join(fact_lines(facts))


def test_a_clip_trimmed_without_reencoding_reads_as_the_frames_it_shows(tmp_path, caplog):
    """A phone's Photos app (an editor's stream copy) trims a clip by its edit list: the frames
    before the cut stay stored from their keyframe on, and players and decoders drop them.
    The clip reads as what it shows: 60 frames, the original's 30-89, no warning; before, 90
    frames (6.0 s of a 5.0 s clip in ``probe``), 'truncated?' after frame 59."""
    from facetransfer.io.video_facts import video_facts
    from facetransfer.io.video_read import read_video, video_info
    whole, cut = tmp_path / "whole.mp4", tmp_path / "trimmed.mp4"
    _run("-f", "lavfi", "-i", "testsrc=size=64x64:rate=30:duration=3", "-c:v", "libx264",
         "-g", "90", "-pix_fmt", "yuv420p", str(whole))
    _run("-ss", "1", "-i", str(whole), "-c", "copy", str(cut))
    info = video_info(cut)
    assert info.n_frames == 60 and info.steps is None and info.fps == 30
    assert video_facts(cut).seconds == 2.0
    caplog.clear()
    frames, _ = read_video(cut)
    original, _ = read_video(whole)
    assert len(frames) == 60 and not [r for r in caplog.records if r.levelname == "WARNING"]
    assert np.abs(frames.astype(int) - original[30:].astype(int)).mean() < 2
    later, _ = read_video(cut, start=40, max_frames=1)
    assert np.abs(later[0].astype(int) - original[70].astype(int)).mean() < 2


def test_a_trimmed_clip_of_variable_rate_keeps_its_frames_on_their_times(tmp_path):
    """The same trim of a phone's clip with a gap (frames 60-69 dropped): its timeline is of
    the frames shown, from the cut on, so frame ``k`` is the original's ``30 + k`` (the one
    before the gap, across it); before, the 30 hidden frames were counted into it: 90 steps
    for a 2-second clip, the gap placed 1 s early."""
    from facetransfer.io.video_read import read_video, video_info
    whole, cut = tmp_path / "whole.mp4", tmp_path / "trimmed.mp4"
    _run("-f", "lavfi", "-i", "testsrc=size=64x64:rate=30:duration=3", "-vf",
         "select='not(between(n\\,60\\,69))'", "-fps_mode", "passthrough", "-c:v", "libx264",
         "-g", "90", "-pix_fmt", "yuv420p", str(whole))
    _run("-ss", "1", "-i", str(whole), "-c", "copy", str(cut))
    info = video_info(cut)
    assert info.n_frames == 60 and info.steps is not None
    frames, _ = read_video(cut)
    original, _ = read_video(whole)          # its own timeline: step k is frame k, held
    assert len(frames) == 60 and len(original) == 90
    assert np.abs(frames.astype(int) - original[30:].astype(int)).mean() < 2


def test_an_overlay_of_the_first_frames_from_a_longer_track(quick_model, quick_model_path,
                                                            tmp_path, capsys):
    """``track CLIP --from-track T.npz --overlay OV.mp4 --max-frames 3`` draws the clip's
    first 3 frames with the track's first 3, as ``puppet`` and ``transfer`` take the first N
    of a longer track; before, it was refused: 'track T.npz has 8 frames, but video CLIP has
    3' (the clip has 8: --max-frames cut it)."""
    from conftest import clip_with_points
    from facetransfer.cli.main import main
    from facetransfer.io.video import read_video
    from facetransfer.track import Track
    video, _, _ = clip_with_points(quick_model, 8, 5, tmp_path)
    F, whole = 8, tmp_path / "whole.npz"
    Track(25.0, (320, 240), np.tile(np.eye(3), (F, 1, 1)), np.full(F, 1e-3),
          np.full((F, 2), 160.0), {"identity": np.zeros((F, 5)), "expression": np.zeros((F, 5))},
          np.zeros((F, 68, 2)), np.ones(F), np.zeros(F, bool), quick_model.content_hash,
          ("identity", "expression")).save(whole)
    ov = tmp_path / "ov.mp4"
    code = main(["track", str(video), "--model", str(quick_model_path), "--from-track",
                 str(whole), "--overlay", str(ov), "--max-frames", "3"])
    assert code == 0, capsys.readouterr().err
    assert read_video(ov)[0].shape[0] == 3


@pytest.mark.parametrize("turn", [0, 90, 180, 270])
@pytest.mark.parametrize("flip", ["-display_hflip", "-display_vflip"])
def test_a_video_mirrored_by_its_display_matrix_is_read_as_players_show_it(tmp_path, turn,
                                                                           flip):
    """A display matrix that mirrors as well as turns (a front camera's clip mirrored by its
    header): OpenCV turned it only, so the frames were read mirrored against what players and
    ffmpeg show (a phone clip's track: eyeBlinkRight r 0.865 against the clean clip's,
    landmarks 15.6 px off; now 0.999, 1.1 px). Every frame read, from the start and from a
    later one, is ffmpeg's, and ``probe`` says it is mirrored."""
    from facetransfer.io.video_facts import fact_lines, video_facts
    from facetransfer.io.video_read import iter_frames, read_video
    flat, clip = tmp_path / "flat.mp4", tmp_path / "mirrored.mp4"
    _run("-f", "lavfi", "-i", "testsrc=size=96x64:rate=10:duration=1", "-c:v", "libx264",
         "-pix_fmt", "yuv444p", "-qp", "0", str(flat))
    _run("-display_rotation", str(turn), flip, "-i", str(flat), "-c", "copy", str(clip))
    frames, _ = read_video(clip)
    shape = frames.shape[1:]
    raw = subprocess.run([FF, "-v", "error", "-i", str(clip), "-f", "rawvideo", "-pix_fmt",
                          "rgb24", "-"], capture_output=True, check=True).stdout
    shown = np.frombuffer(raw, np.uint8).reshape((-1, *shape))
    assert len(frames) == len(shown) == 10
    assert np.abs(frames.astype(int) - shown.astype(int)).mean() < 1
    later = next(iter(iter_frames(clip, start=6)))
    assert np.abs(later.astype(int) - shown[6].astype(int)).mean() < 1
    assert "mirrored by its display matrix" in fact_lines(video_facts(clip))[0]
    unturned = tmp_path / "plain.mp4"
    _run("-display_rotation", str(turn), "-i", str(flat), "-c", "copy", str(unturned))
    assert not video_facts(unturned).mirrored


def test_the_track_cache_is_keyed_by_the_frame_readers_too():
    """A track cached before the readers came to read a trimmed or mirrored clip right is not
    taken after: the code fingerprint of the track cache digests the readers that decide a
    clip's frames (before, only ``track/`` and the model: a mirrored clip's cached track,
    left and right swapped, was taken again)."""
    from pathlib import Path

    from facetransfer.track import cache
    root = Path(cache.__file__).resolve().parent.parent
    files = cache.fingerprinted_files(root)
    for name in ("io/video_read.py", "io/video_timeline.py", "io/video_display.py"):
        assert root / name in files
    assert all(f.is_file() for f in files)
