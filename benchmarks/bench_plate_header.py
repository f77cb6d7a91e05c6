"""A plate's frame rate, timecode and pixel aspect through ``facetransfer`` (io.plate_header).

The first four seconds of ``WDA_KatieHill_000`` (25 fps) as the plates a scan or a conform hands
over, each frame's header saying 25 fps and its timecode from 10:00:00:00 on: 10-bit DPX
(ITU-R 709, written by OpenImageIO) and half-float OpenEXR (written by OpenEXR's bindings); and
the same frames as a lossless video (FFV1, 25 fps, the same start timecode), the reference.
Run by the command of this tree and of the revision before (``--before``, default ``a1daf76``:
a sequence read at 24 fps unless ``--sequence-fps`` says otherwise, of square pixels), in
fresh processes. Judged:

- each plate given the expressions of ``driving_d6`` (30 fps, matched by time) and written as
  MP4 with the result's track saved: the rate the result plays at, its start timecode
  (``ffprobe``), and its performance against the one the lossless video got (the reference,
  this tree): the mean absolute difference of the 52 activations, and how many frames the
  performance has drifted by the clip's end (the shift that lines the last frames up);
- the lossless video rewritten as a DPX and an OpenEXR sequence: each frame's header's rate and
  timecode against the video's rate and its start timecode counted on;
- an anamorphic plate (the frames squeezed to half their width, the DPX header's pixel aspect
  ratio 2): ``facetransfer track`` of it against the track of the lossless video (the same
  face unsqueezed): the 52 activations' mean absolute difference, the identity weights' RMS
  difference, the head scale's median ratio.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_plate_header.py --out out/benchmarks

Writes ``OUT/plate_header.json`` and ``OUT/plate_header.png``.
"""

from __future__ import annotations

import sys
import tempfile
from fractions import Fraction
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import save_json, save_plot  # noqa: E402
from _revision import now_and_before, run_command  # noqa: E402

SECONDS = 4
FPS = 25.0
START = "10:00:00:00"


def make_plates(clip: Path, folder: Path) -> dict:
    """The clip's first seconds as a lossless video with a timecode, a DPX and an OpenEXR
    plate whose headers say the rate and each frame's timecode (module notes)."""
    import OpenEXR
    import OpenImageIO as oiio

    from facetransfer.io.exr import srgb_decode
    from facetransfer.io.plate_header import timecode_after, timecode_word
    from facetransfer.io.video import VideoOptions, read_video, write_video

    frames = read_video(clip, max_frames=int(SECONDS * FPS))[0]
    video = folder / "target.mkv"
    write_video(video, frames, FPS, options=VideoOptions(crf=0, timecode=START))
    for d in ("dpx", "exr"):
        (folder / d).mkdir()
    for i, rgb in enumerate(frames):
        tc = timecode_after(START, i, FPS)
        spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, "uint16")
        spec.attribute("oiio:BitsPerSample", 10)
        spec.attribute("dpx:Transfer", "ITU-R 709-4")
        spec.attribute("dpx:FrameRate", FPS)
        spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"),
                       np.array([timecode_word(tc), 0], np.uint32))
        out = oiio.ImageOutput.create("dpx")
        out.open(str(folder / "dpx" / f"p.{1001 + i:04d}.dpx"), spec)
        out.write_image(((rgb.astype(np.uint32) * 1023 * 2 + 255) // 510 * 64).astype(np.uint16))
        out.close()
        code = OpenEXR.TimeCode()
        code.hours, code.minutes, code.seconds, code.frame = (int(v) for v in tc.split(":"))
        header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage,
                  "framesPerSecond": Fraction(int(FPS)), "timeCode": code}
        with OpenEXR.File(header, {"RGB": srgb_decode(rgb).astype(np.float16)}) as f:
            f.write(str(folder / "exr" / f"p.{1001 + i:04d}.exr"))
    return {"video": video, "DPX": folder / "dpx" / "p.%04d.dpx",
            "OpenEXR": folder / "exr" / "p.%04d.exr"}


def transfer(target: Path, source: Path, out: Path, src: Path | None) -> tuple[int, str]:
    """``facetransfer transfer`` of ``target`` with ``source``'s expressions into ``out`` (and
    its track beside it)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    return run_command(["transfer", "--target", target, "--expression-from", source,
                        "--out", out, "--save-track", out.with_suffix(".npz")], src)


def squeezed_plate(video: Path, folder: Path) -> Path:
    """``video``'s frames squeezed to half their width as a 10-bit DPX plate whose header says
    the pixels are twice as wide as tall (an anamorphic scan's), 25 fps."""
    import cv2
    import OpenImageIO as oiio

    from facetransfer.io.video import read_video

    folder.mkdir()
    for i, rgb in enumerate(read_video(video)[0]):
        narrow = cv2.resize(rgb, (rgb.shape[1] // 2, rgb.shape[0]), interpolation=cv2.INTER_AREA)
        spec = oiio.ImageSpec(narrow.shape[1], narrow.shape[0], 3, "uint16")
        spec.attribute("oiio:BitsPerSample", 10)
        spec.attribute("dpx:Transfer", "ITU-R 709-4")
        spec.attribute("dpx:FrameRate", FPS)
        spec.attribute("PixelAspectRatio", 2.0)
        out = oiio.ImageOutput.create("dpx")
        out.open(str(folder / f"p.{1001 + i:04d}.dpx"), spec)
        codes = (narrow.astype(np.uint32) * 1023 * 2 + 255) // 510
        out.write_image((codes << 6 | codes >> 4).astype(np.uint16))
        out.close()
    return folder / "p.%04d.dpx"


def judged_capture(track: Path, reference) -> dict:
    """A track of the anamorphic plate against the lossless video's."""
    from facetransfer.track import Track

    got = Track.load(track)
    n = min(got.n_frames, reference.n_frames)
    ident = got.weights["identity"][0] - reference.weights["identity"][0]
    return {"pixel_aspect": got.pixel_aspect,
            "activation_mae_vs_video": round(float(np.abs(
                got.blendshapes[:n] - reference.blendshapes[:n]).mean()), 4),
            "identity_rms_vs_video": round(float(np.sqrt(np.mean(ident ** 2))), 4),
            "head_scale_ratio": round(float(np.median(got.scale[:n] / reference.scale[:n])), 3)}


def judged_video(out: Path, reference: np.ndarray) -> dict:
    """The result's rate and timecode, and its performance against the reference's."""
    from facetransfer.io.video_display import timecode_of
    from facetransfer.io.video_read import video_info
    from facetransfer.track import Track

    got = Track.load(out.with_suffix(".npz")).blendshapes
    n = min(len(got), len(reference))
    return {"fps": round(video_info(out).fps, 3), "timecode": timecode_of(out),
            "frames": int(len(got)),
            "activation_mae_vs_video": round(float(np.abs(got[:n] - reference[:n]).mean()), 4),
            "late_frames_lag": _lag(got[:n], reference[:n])}


def _lag(got: np.ndarray, reference: np.ndarray, window: int = 40, most: int = 8) -> int:
    """The shift ``s`` (target frames, within ``most``) that best lines the result's frames
    ``k`` near the clip's end up with the reference's ``k + s``: how far its time has drifted
    (positive: frame ``k`` shows what the reference shows later)."""
    a, b = len(got) - window - most, len(got) - most
    errors = {s: float(np.abs(got[a:b] - reference[a + s:b + s]).mean())
              for s in range(-most, most + 1)}
    return min(errors, key=errors.get)


def judged_frames(pattern: Path, n: int) -> dict:
    """Each written frame's header against the video's rate and its timecode counted on."""
    from facetransfer.io.plate_header import frame_header, timecode_after

    right = 0
    for i in range(n):
        t = frame_header(str(pattern) % i)
        right += int(t.fps is not None and abs(t.fps - FPS) < 1e-3
                     and t.timecode == timecode_after(START, i, FPS))
    return {"frames": n, "frames_with_rate_and_timecode": right}


def plot(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    rows = [r for r in report["plates"] if "fps" in r]
    ana = {k: v for k, v in report["anamorphic"].items() if "pixel_aspect" in v}
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(10, 2.9))
    names = [f"{r['plate']}\n{r['tree']}" for r in rows]
    a.bar_label(a.bar(names, [r["fps"] for r in rows]), fontsize=7)
    a.axhline(FPS, color="k", lw=0.8, ls="--")
    a.set_ylabel("result's rate, fps (plate: 25)")
    b.bar_label(b.bar(names, [r["activation_mae_vs_video"] for r in rows]), fmt="%.3f",
                fontsize=7)
    b.set_ylabel("performance vs the video's, MAE")
    c.bar_label(c.bar([f"anamorphic\n{k}" for k in ana],
                      [v["activation_mae_vs_video"] for v in ana.values()]), fmt="%.3f",
                fontsize=7)
    c.set_ylabel("capture vs unsqueezed, MAE")
    for ax in (a, b, c):
        ax.tick_params(labelsize=7)
    save_plot(fig, path)


def rate_rows(paths: dict, source: Path, trees: dict, folder: Path, reference) -> list:
    """Each plate given the source's expressions, by each tree (module notes)."""
    rows = []
    for plate in ("DPX", "OpenEXR"):
        for tree, src in trees.items():
            res = folder / plate / tree / "r.mp4"
            status, err = transfer(paths[plate], source, res, src)
            row = {"plate": plate, "tree": tree, "status": status}
            row |= judged_video(res, reference) if status == 0 else {"error": err}
            rows.append(row)
            print(row, flush=True)
    return rows


def frame_rows(paths: dict, source: Path, trees: dict, folder: Path, n: int) -> dict:
    """The lossless video rewritten as DPX and OpenEXR frames, by each tree."""
    rows = {}
    for suffix in ("dpx", "exr"):
        for tree, src in trees.items():
            pattern = folder / f"seq_{suffix}_{tree}" / f"r.%04d.{suffix}"
            status, err = transfer(paths["video"], source, pattern, src)
            rows[f"{suffix} {tree}"] = judged_frames(pattern, n) if status == 0 else \
                {"error": err}
            print(suffix, tree, rows[f"{suffix} {tree}"], flush=True)
    return rows


def anamorphic_rows(video: Path, trees: dict, folder: Path) -> dict:
    """``track`` of the anamorphic plate by each tree against the lossless video's track."""
    from facetransfer.track import Track

    plate = squeezed_plate(video, folder / "anamorphic")
    status, err = run_command(["track", video, "--out", folder / "video_track.npz"], None)
    assert status == 0, err
    reference = Track.load(folder / "video_track.npz")
    rows = {}
    for tree, src in trees.items():
        out = folder / f"anamorphic_{tree}.npz"
        status, err = run_command(["track", plate, "--out", out], src)
        rows[tree] = judged_capture(out, reference) if status == 0 else {"error": err}
        print("anamorphic", tree, rows[tree], flush=True)
    return rows


def main() -> int:
    from facetransfer.assets import data_dir
    from facetransfer.track import Track

    out, trees, before = now_and_before(__doc__, "a1daf76")
    data = data_dir()
    source = data / "video" / "driving_d6.mp4"
    report = {"benchmark": "a plate's rate, timecode and pixel aspect", "before": before}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = make_plates(data / "video" / "WDA_KatieHill_000.mp4", folder)
        status, err = transfer(paths["video"], source, folder / "ref" / "r.mp4", None)
        assert status == 0, err
        reference = Track.load(folder / "ref" / "r.npz").blendshapes
        report["plates"] = rate_rows(paths, source, trees, folder, reference)
        report["video_to_frames"] = frame_rows(paths, source, trees, folder, len(reference))
        report["anamorphic"] = anamorphic_rows(paths["video"], trees, folder)
    save_json(report, out / "plate_header.json")
    plot(report, out / "plate_header.png")
    print(f"wrote {out / 'plate_header.json'} and {out / 'plate_header.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
