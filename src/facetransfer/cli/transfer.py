"""``facetransfer`` subcommands of this area (filled in by its issue)."""

from __future__ import annotations


def register(sub) -> None:
    """Add this module's subcommands to the facetransfer parser."""
