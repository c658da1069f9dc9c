"""``drivesense identify frf``: ball-screw parameters from an FRF excitation trace."""

from __future__ import annotations

import typer

__all__ = ["register"]


def register(identify_app: typer.Typer) -> None:
    """Add this module's command to the ``identify`` group."""
