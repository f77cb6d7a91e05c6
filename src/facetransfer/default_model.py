"""The default model: built once from the ``ict-arkit`` data set into the user cache, on first use.

Every command that needs a model and is given none uses it (``track``, ``transfer``, ``edit``,
``puppet``, ``demo``, ``export``, ``view``, ``batch``, ``synth-video``, ``texture default`` and
``lift``, ``render``, ``model info``, ``synth``, ``sheet`` and ``dials``). Its expressions
are the ARKit blendshapes (:mod:`facetransfer.arkit`), its identities are drawn from the
ICT-FaceKit's 100-component identity space (§4.1). The file lives at
:func:`default_model_path`, named by what builds it (:func:`build_recipe`: the code and data
of every module its build runs), so that an upgrade that changes how the model is built never
leaves the old build in use; a damaged file is rebuilt, and so is one its record
(:func:`recipe_path`) does not say this recipe built. The recipe is not in the model's
metadata, so a build of the same bits keeps the model's content hash, and the tracks and face
files made with it stay its own.

Sits beside :mod:`facetransfer.model` (it only composes :mod:`facetransfer.datasets` and
:func:`facetransfer.model.build_model`), below every consumer.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
from pathlib import Path
from typing import Callable

from .errors import ModelFileError

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_DATASET", "default_model_path", "recipe_path", "build_recipe",
           "dataset_ranks", "load_default_model", "is_default_model", "kept_model",
           "kept_model_hint", "stated_hash"]

#: The data set of the default model.
DEFAULT_DATASET = "ict-arkit"
#: Bump when the default model's recipe changes in a way its code does not show (it is in
#: :func:`build_recipe`, hence in the file's name).
DEFAULT_MODEL_VERSION = 1
#: Default models of other recipes kept beside this version's (the newest; 0.47 GB each): a
#: switch back to another version (two checkouts sharing a user cache) finds its own.
KEEP_OTHERS = 2
#: The default model files' names begin so (then ``-RECIPE.npz``; before the recipe, ``.npz``).
_STEM = f"{DEFAULT_DATASET}-default-v{DEFAULT_MODEL_VERSION}"

Progress = Callable[[int, int], None]


def default_model_path() -> Path:
    """Where this version's default model is cached (the file may not exist yet): named by
    its :func:`build_recipe` (``ict-arkit-default-v1-RECIPE.npz``), so that two versions sharing
    a user cache keep one each, not rebuilding it in turn."""
    from .assets import cache_dir

    return cache_dir() / "models" / f"{_STEM}-{_recipe()}.npz"


@functools.lru_cache(maxsize=1)
def _recipe() -> str:
    """:func:`build_recipe` of this process's package (its code does not change under it)."""
    return build_recipe()


def recipe_path() -> Path:
    """The record beside :func:`default_model_path` of what built that file: its
    :func:`build_recipe` and its content hash (JSON)."""
    path = default_model_path()
    return path.with_name(f"{path.stem}.recipe.json")


def build_recipe(*, root: Path | None = None) -> str:
    """A digest of what builds the default model: the code and data files of every module the
    build can run (:func:`facetransfer.code_digest.closure_digest` of this module, in the
    package at ``root``: by default this one). They hold all of it: :data:`DEFAULT_MODEL_VERSION`,
    the recipe file (``ict_recipes.json``: the data set's expressions, identities and ranks),
    the ICT-FaceKit's commit and its files' sha256 table (:mod:`facetransfer.assets`), the
    builder's version and code. Not the libraries' versions: a model built with another NumPy
    is as good, and rebuilding it would orphan its tracks for its last bits."""
    from . import code_digest

    return code_digest.closure_digest([__name__], f"default-v{DEFAULT_MODEL_VERSION}",
                                      root=root or code_digest.PACKAGE_ROOT)


def dataset_ranks(dataset) -> dict[str, int]:
    """Recipe ranks of an ICT data set (``default_ranks`` in its provenance) clipped to the mode
    sizes; empty (full ranks) for other data sets."""
    rec = dict(dataset.provenance.get("default_ranks") or {})
    sizes = dict(zip(dataset.mode_names, dataset.shape))
    return {m: min(int(r), sizes[m]) for m, r in rec.items() if m in sizes}


def load_default_model(*, progress: Progress | None = None, announce: Callable[[str], None]
                       | None = None):
    """Load the default model, building and caching it first if needed: none is cached, the
    cached one is damaged, or another recipe or code built it (:func:`build_recipe` against
    :func:`recipe_path`'s record: a model cached without a record, by a version before it, is
    rebuilt too).

    Parameters
    ----------
    progress : callable(done, total), optional
        Called per identity while the data set is built (a build only).
    announce : callable(str), optional
        Called once with a one-line message before a build starts (the CLI prints it): the
        first build's, or a stale model's rebuild's.

    Returns
    -------
    MultilinearModel
    """
    path, recipe = default_model_path(), _recipe()
    model, stale = _cached(path, recipe)
    if model is not None:
        return model
    with _build_lock(path, announce):
        model, stale = _cached(path, recipe)    # built meanwhile by the process waited for
        if model is not None:
            return model
        if announce is not None:
            announce(f"rebuilding the default model ({DEFAULT_DATASET}) into {path}: the "
                     f"cached one ({stale.name}) was built by another version of its recipe "
                     "or code" if stale else f"building the default model ({DEFAULT_DATASET}) "
                     f"once into {path}")
        model = _build(path, progress, None)
        _record(model, recipe)
    _prune_others(path)
    return model


def _cached(path: Path, recipe: str) -> tuple:
    """``(model, None)`` where ``path`` holds the model ``recipe`` built (its record says so),
    else ``(None, the stale file to name)``: ``path`` itself where it holds another build, or
    the newest default model of another recipe beside it (:func:`_older`), or None."""
    from .model import load_model

    stale = _older(path)
    if path.is_file():
        try:
            model = load_model(path)
        except ModelFileError as exc:
            log.warning("cached default model is unusable (%s); rebuilding", exc)
        else:
            if _recorded(model) == recipe:
                return model, None
            stale = path
            del model         # its core's mapped pages (0.45 GB) not held over the build
    return None, stale


@contextlib.contextmanager
def _build_lock(path: Path, announce: Callable[[str], None] | None):
    """Hold an exclusive lock (``flock``) on a file beside ``path`` for a build: two commands
    started at once (after an upgrade, every command rebuilds) built it side by side, twice the
    1.9 GB and the CPU, each renaming its file over the other's; the later one waits for the
    first (said through ``announce``) and takes its model. A cache where no lock can be taken
    (read-only, a network file system without locks) builds unlocked, as before."""
    import fcntl
    import os

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path.with_name(f".{_STEM}.build.lock"), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if announce is not None:
                announce(f"waiting for another command building the default model into "
                         f"{path.parent}")
            with contextlib.suppress(OSError):
                fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            pass
        yield
    finally:
        os.close(fd)


def _older(path: Path) -> Path | None:
    """The newest default model file beside ``path`` of another recipe (another version's, or
    one named before the recipe was), or None."""
    from .assets import others_beside

    try:
        return next(iter(others_beside(path, f"{_STEM}*.npz")), None)
    except OSError:
        return None


def kept_model(content_hash: str) -> Path | None:
    """The default model file of another version kept beside this one's
    (:data:`KEEP_OTHERS`; one named before the recipe was, ``ict-arkit-default-v1.npz``) that
    holds the model of ``content_hash`` (its metadata's hash, or a prefix of it), newest first;
    None where none does. A track made with the default model before a rebuild gave it another
    hash names this file, which then holds the model it was made with."""
    if not content_hash:
        return None
    from .assets import others_beside

    try:
        others = others_beside(default_model_path(), f"{_STEM}*.npz")
    except OSError:
        return None
    return next((p for p in others if (stated_hash(p) or "").startswith(content_hash)), None)


def kept_model_hint(content_hash: str) -> str:
    """What a refusal of a file made with the model of ``content_hash`` adds where that model
    is a default model kept of another version (:func:`kept_model`): " (made with the default
    model of another version, kept at P: give --model P)"; else ``""``."""
    kept = kept_model(content_hash)
    return "" if kept is None else (f" (made with the default model of another version, kept "
                                    f"at {kept}: give --model {kept})")


def stated_hash(path: Path) -> str | None:
    """The sha256 the metadata of the model file ``path`` states (read, not checked: the
    file's content is checked as it is loaded), None where it is no readable model file."""
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["metadata"]))
    except (OSError, ValueError, KeyError, EOFError):
        return None
    return meta.get("sha256") if isinstance(meta, dict) else None


def _prune_others(path: Path) -> None:
    """Remove the default model files of other recipes beside ``path`` (and their records)
    but the :data:`KEEP_OTHERS` newest; a cache that cannot be pruned is left (logged)."""
    from .assets import prune_beside

    prune_beside(path, f"{_STEM}*.npz", KEEP_OTHERS, "another version's default model",
                 also=lambda p: p.with_name(f"{p.stem}.recipe.json"))


def _recorded(model) -> str | None:
    """The :func:`build_recipe` that :func:`recipe_path` records for ``model`` (the file as
    loaded: the record names its content hash); None where there is no record (a model built
    before the record existed), it is unreadable, or it is another file's."""
    try:
        record = json.loads(recipe_path().read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("sha256") != model.content_hash:
        return None
    return record.get("recipe")


def _record(model, recipe: str) -> None:
    """Write :func:`recipe_path` for ``model`` just saved: built by ``recipe``. A record that
    cannot be written leaves the model to be rebuilt next time (warned)."""
    from .io.atomic import write_text_atomic

    try:
        write_text_atomic(recipe_path(), json.dumps({"recipe": recipe,
                                                     "sha256": model.content_hash}))
    except (OSError, ValueError) as exc:   # OutputError: a full disk, a read-only cache
        log.warning("could not record how the default model was built (%s)", exc)


def _build(path: Path, progress, announce):
    from .datasets import deformation, load_dataset
    from .model import build_model
    from .threads import one_blas_thread

    del deformation       # imported for SciPy's BLAS, loaded before it is held (below)

    if announce is not None:
        announce(f"building the default model ({DEFAULT_DATASET}) once into {path}")
    # on one BLAS thread whatever the command: OpenBLAS orders its sums by its thread count,
    # so a build on two threads (``probe``, ``export``) and one on one (``track``, ``demo``:
    # cli.main.SERIAL_POOLS) differed in their last bits, hence in their content hash
    # (49fc4338eee2 against 4bd74ef47e95 here): a track made with one was refused by the other.
    # A library loaded inside the block is not held: SciPy's own OpenBLAS, loaded by the
    # deformation transfer, ran on every core where the process had not loaded it before (the
    # CLI's builds 5ef31ecd1964, pytest's ac4061d4553f); it is loaded above.
    with one_blas_thread():
        ds = load_dataset(DEFAULT_DATASET, progress=progress)
        model = build_model(ds, dataset_ranks(ds), refine=False)
    del ds
    model.provenance["default_model"] = True  # read by is_default_model
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    log.info("built the default model %s", path)
    return model


def is_default_model(model) -> bool:
    """Whether ``model`` was built by :func:`load_default_model` (its provenance says so)."""
    prov = getattr(model, "provenance", {}) or {}
    return prov.get("dataset") == DEFAULT_DATASET and prov.get("default_model") is True
