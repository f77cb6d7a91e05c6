"""What a refusal of a file made with another model than the one given adds: how to give the
right one.

A track, a face file or an export refused because it was made with another model than
``--model``'s names the way to its model where it is a default model: this version's (leave
out ``--model``: the command loads it itself) or another version's kept in the cache
(:func:`facetransfer.default_model.kept_model_hint`). A module of its own, not a function of
:mod:`facetransfer.default_model`: the default model is rebuilt whenever that module's code
changes (:func:`facetransfer.default_model.build_recipe`), and a message is no reason for it.
"""

from __future__ import annotations

import json

__all__ = ["current_default_hash", "model_hint"]


def current_default_hash() -> str | None:
    """The content hash of this version's default model as its build's record states it
    (:func:`facetransfer.default_model.recipe_path`: read, not checked), None where it is not
    built yet, or the record is another recipe's or unreadable: the model
    :func:`facetransfer.default_model.load_default_model` loads without a build."""
    from . import default_model as dm

    try:
        record = json.loads(dm.recipe_path().read_text())
    except (OSError, ValueError):
        return None
    path = dm.default_model_path()        # named by this version's recipe
    if not isinstance(record, dict) or not path.stem.endswith(f"-{record.get('recipe')}") \
            or not path.is_file():
        return None
    found = record.get("sha256")
    return found if isinstance(found, str) else None


def model_hint(content_hash: str) -> str:
    """What a refusal of a file made with the model of ``content_hash`` adds: " (made with the
    default model: leave out --model)" where that is this version's default model (an older
    recipe's file kept in the cache may hold the same model, and naming it sent the user to a
    cache file for what no option gives), else
    :func:`facetransfer.default_model.kept_model_hint` (another version's, kept: its file), or
    ``""``."""
    from .default_model import kept_model_hint

    if content_hash and (current_default_hash() or "").startswith(content_hash):
        return " (made with the default model: leave out --model)"
    return kept_model_hint(content_hash)
