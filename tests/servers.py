"""Real servers the service tests run against: Debian's mosquitto on a free loopback port.

``scripts/test`` installs mosquitto (and chromium); with ``CI=true`` a missing binary fails the test instead
of skipping it.
"""

from __future__ import annotations

import os
import shutil

import pytest

from drivesense.serve.broker import LocalBroker, free_port

__all__ = ["Mosquitto", "free_port", "require_binary"]


def require_binary(name: str, *candidates: str) -> str:
    """Path of a program; skip the test without it (fail with CI=true)."""
    for c in (name, *candidates):
        path = shutil.which(c) or (c if os.path.isfile(c) and os.access(c, os.X_OK) else None)
        if path:
            return path
    message = f"{name} is not installed (scripts/test installs it from Debian's packages)"
    if os.environ.get("CI") == "true":
        pytest.fail(message)
    pytest.skip(message)


class Mosquitto(LocalBroker):
    """:class:`drivesense.serve.broker.LocalBroker`, skipping the test when mosquitto is missing (failing with
    CI=true)."""

    def __init__(self) -> None:
        require_binary("mosquitto", "/usr/sbin/mosquitto")
        super().__init__()
