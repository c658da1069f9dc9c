"""``drivesense wear calibrate|track: cutting coefficients from spindle power, tool-wear tracking``."""

from __future__ import annotations

import typer

__all__ = ["register"]


def register(root: typer.Typer) -> None:
    """Add this module's commands (or command group) to the root application."""
