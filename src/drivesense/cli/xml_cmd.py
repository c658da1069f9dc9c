"""``drivesense xml validate|export|import|transform: the XML sensor-data format``."""

from __future__ import annotations

import typer

__all__ = ["register"]


def register(root: typer.Typer) -> None:
    """Add this module's commands (or command group) to the root application."""
