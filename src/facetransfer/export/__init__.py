"""Exports animators can use (beyond the paper): Live Link Face CSV, glTF, USD, MediaPipe JSON.

A track's ARKit activations (``TRACK.npz`` key ``blendshapes``) and head pose go out in the
formats that Blender, Unreal, Maya, Unity and tools written against MediaPipe read:

==========  ============  ===========================================================
format      module        what
==========  ============  ===========================================================
livelink    livelink      Live Link Face CSV take (the app's columns, by position)
glb         gltf          glTF 2.0 binary: the person, 52 morph targets, one animation
usd         usd           UsdSkel blend shapes + SkelAnimation (needs ``usd-core``)
json        mpjson        per-frame scores in MediaPipe Face Landmarker's layout
==========  ============  ===========================================================

The glb's and the USD's eyeballs, behind the face's eye holes, turned by its gaze and hidden
while its lids are shut, and the dark eye sockets behind the holes, are
:mod:`facetransfer.export.gltf_eyes`; their teeth, on the dental arches behind the lips (the
lower row moved by the jaw), :mod:`facetransfer.export.teeth`. What every format shares (the
model check, the activations, the head pose) is :mod:`facetransfer.export.common`. The browser dial editor is
:mod:`facetransfer.export.viewer`; a neutral pose for the curves (Live Link Face's calibration)
is :mod:`facetransfer.export.neutral`.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from ..io.atomic import check_output_path
from ..track.project import held_lost
from .common import (ExportError, activations_from_weights, require_activations, resolve_model,
                     with_clip_facts)
from .neutral import with_neutral
from .usd import USD_SUFFIXES

__all__ = ["FORMATS", "FORMAT_SUFFIXES", "GEOMETRY_FORMATS", "ExportError", "export_track",
           "format_of"]

log = logging.getLogger(__name__)

#: Format name -> usual file suffix.
FORMATS: dict[str, str] = {"livelink": ".csv", "glb": ".glb", "usd": ".usd", "json": ".json"}
#: Format name -> the file suffixes it is written under (the first: :data:`FORMATS`'); a
#: glb is binary glTF, never ``.gltf`` (JSON with its buffers beside it).
FORMAT_SUFFIXES: dict[str, tuple[str, ...]] = {
    "livelink": (".csv",), "glb": (".glb",), "usd": USD_SUFFIXES, "json": (".json",)}
#: The formats that write the mesh (the track's person and its blend shapes), so need the
#: track's model (``export --model``, else the default model); the others write curves alone.
GEOMETRY_FORMATS: tuple[str, ...] = ("glb", "usd")


def format_of(out: str | os.PathLike, fmt: str | None = None) -> str:
    """The export format of the file ``out``: ``fmt`` when given (its name must end as that
    format's files do, :data:`FORMAT_SUFFIXES`), else the one its extension names.

    Raises
    ------
    ExportError
        An unknown ``fmt``; no ``fmt`` and an extension no format has.
    OutputError
        ``out`` named for another format than ``fmt`` (a glb named ``face.usd`` is a file
        that USD cannot open).
    """
    from ..io.output_names import check_output_suffix, suffix_list

    if fmt is not None and fmt not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    suffix = Path(out).suffix.lower()
    named = next((f for f, s in FORMAT_SUFFIXES.items() if suffix in s), None)
    if suffix == ".gltf" and fmt in (None, "glb"):   # the text form, with its files beside
        raise ExportError(f"{out}: glTF is written as one binary file, a .glb (its mesh, "
                          f"animation and texture inside); name it {Path(out).stem}.glb")
    if fmt is None:
        if named is None:
            raise ExportError(
                f"cannot tell the export format of {out} from its extension: name it "
                + ", ".join(f"{suffix_list(s)} ({f})" for f, s in FORMAT_SUFFIXES.items())
                + ", or give --format")
        return named
    check_output_suffix(out, FORMAT_SUFFIXES[fmt], f"a {fmt} export", flag="output",
                        hint=f" (or --format {named})" if named else "")
    return fmt


def export_track(track, fmt: str | None, out: str | os.PathLike, *, model=None,
                 overwrite: bool = False,
                 texture=None, neutral=None, timecode: str | None = "source",
                 labels: str | None = None) -> Path:
    """Write ``track`` in format ``fmt`` to ``out`` and return the path.

    Parameters
    ----------
    track : facetransfer.track.Track
        With ARKit activations (``blendshapes``), or with expression weights of a model whose
        expressions are ARKit blendshapes (``model``, else the default model if the track is
        of it): the activations are made from them. A lost frame: its nearest tracked one's.
    fmt : {"livelink", "glb", "usd", "json"} or None
        None: the format ``out``'s extension names (:func:`format_of`).
    out : path-like
        Its folder must exist; an existing file is replaced only with ``overwrite``.
    model : MultilinearModel, optional
        The track's model; None: the default model, if the track was made with it.
    overwrite : bool
    texture : path or (H, W, 3) uint8, optional
        Base-colour texture in the template's UV layout (``glb`` only).
    neutral : int or "auto", optional
        Measure the activations from this frame's (:mod:`facetransfer.export.neutral`: Live
        Link Face's calibration); None: as tracked.
    timecode : str or None
        ``livelink``: the first row's timecode (``HH:MM:SS:FF``, ``;`` for drop frame);
        ``"source"`` (default): the start timecode of the video the track was made from, where
        it has one (:func:`facetransfer.export.livelink.source_timecode`); None:
        ``00:00:00:00``. ``usd``: ``"source"`` (default) starts the time codes at the first
        frame number of the image sequence the track was made from (1001 for a plate numbered
        from 1001; :func:`facetransfer.export.usd.source_first_frame`), None at 0. Both as the
        track records them (read when it was tracked: the clip may have moved since); a track
        made before tracks recorded them reads them from its clip if it is still there
        (:func:`facetransfer.export.common.clip_facts`). ``usd`` and
        ``glb``: ``"source"`` also records the video's start timecode, where it has one, in the
        file's metadata (the root layer's ``customLayerData["timecode"]``, the glTF's
        ``extras["timecode"]``: neither format has a field of its own for it); ``json`` too
        (a top-level ``"timecode"``).
    labels : {"app", "clip"}, optional
        ``livelink`` only: the rows' timecodes counted as the Live Link Face app counts them,
        in frames of 30 or 60 a second with thousandths (``"app"``, None's: what Unreal's Live
        Link Face importer reads right at any clip rate), or as the clip's timecode counts its
        frames (``"clip"``: frame for frame with a 24, 25 or 50 fps plate's timecode in an
        editor; :func:`facetransfer.export.livelink.format_timecode`).

    Raises
    ------
    ExportError
        Unknown format, no activations, a model that does not match, a texture for a format
        without one, a neutral frame outside the track, a ``timecode`` that is not one.
    """
    fmt = format_of(out, fmt)
    check_output_path(out, overwrite=overwrite)
    _check_options(fmt, texture, timecode, labels)
    if track.blendshapes is None:
        track = _activations_from_weights(track, model)
    require_activations(track)
    track, start = _start(with_neutral(held_lost(track), neutral), timecode)  # as puppet
    if fmt in ("livelink", "json"):
        if model is not None:
            track.check_model(model)
        if fmt == "livelink":
            from .livelink import DEFAULT_LABELS, write_livelink

            return write_livelink(track, out, overwrite=overwrite, start=start,
                                  labels=labels or DEFAULT_LABELS)
        from .mpjson import write_mediapipe_json

        return write_mediapipe_json(track, out, overwrite=overwrite, timecode=start)
    model = resolve_model(track, model)
    if fmt == "glb":
        from .gltf import write_glb

        return write_glb(track, model, out, overwrite=overwrite, texture=texture,
                         timecode=start)
    from .usd import write_usd

    return write_usd(track, model, out, overwrite=overwrite,
                     first_frame=track.source_facts.first_frame if timecode == "source" else 0,
                     timecode=start)


def _check_options(fmt: str, texture, timecode, labels: str) -> None:
    """ExportError for an option that format ``fmt`` does not write."""
    if texture is not None and fmt != "glb":
        raise ExportError(f"a texture is written only into glb files, not {fmt}")
    if timecode not in (None, "source") and fmt != "livelink":
        raise ExportError(f"a start timecode is written only into livelink takes, not {fmt}")
    if labels is not None and fmt != "livelink":
        raise ExportError(f"timecode labels {labels!r} are written only into livelink takes, "
                          f"not {fmt}")


def _start(track, timecode):
    """``(track, start)``: the first frame's timecode, every format's (livelink's rows start
    at it, the others record it), and with ``"source"`` the track with its clip's numbering
    (:func:`with_clip_facts`: a USD's time codes then start at the plate's first number)."""
    if timecode != "source":
        return track, timecode
    track, note = with_clip_facts(track)
    if note:                       # an older track: from its clip's path, if at all
        log.warning("%s", note)
    start = track.source_facts.timecode
    if start is not None:          # a clip's own, taken as it is, but not without a word
        from ..io.plate_header import exact_timecode

        try:
            exact_timecode(start, track.fps)
        except ValueError as exc:
            log.warning("the clip's start %s: the export counts on from it as if it did "
                        "(frames past the last of a second carried into the next)", exc)
    return track, start


def _activations_from_weights(track, model):
    """A track without activations (e.g. one recombined in Python, Fig. 1) with them made from
    its expression weights (:func:`activations_from_weights`) with its model (``model``, else
    the default model if the track is of it); else the track as it is
    (:func:`require_activations` then says what is missing)."""
    if "expression" not in track.weights:
        return track
    try:
        model = resolve_model(track, model)
    except ExportError:            # not the default model's, and none given
        return track
    return activations_from_weights(track, model)
