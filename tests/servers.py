"""Real servers the service tests run against: Debian's mosquitto on a free loopback port.

``scripts/test`` installs mosquitto (and chromium); with ``CI=true`` a missing binary fails the test instead
of skipping it.
"""

from __future__ import annotations

import asyncio
import os
import shutil

import pytest

from drivesense.monitor.broker import LocalBroker, free_port

__all__ = ["Mosquitto", "free_port", "require_binary", "run_until_cuts"]


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
    """:class:`drivesense.monitor.broker.LocalBroker`, skipping the test when mosquitto is missing (failing with
    CI=true)."""

    def __init__(self) -> None:
        require_binary("mosquitto", "/usr/sbin/mosquitto")
        super().__init__()


def run_until_cuts(service, spec, cuts: int, timeout: float = 120.0) -> None:
    """Run a :class:`~drivesense.monitor.service.MonitorService` until its simulated machine ``spec`` has played
    ``cuts`` cuts (as fast as it goes with ``speed=0``), then stop it; the machine keeps its buffers."""

    async def main():
        stop = asyncio.Event()

        async def stopper():
            while spec.source.cuts < cuts:
                await asyncio.sleep(0.02)
            stop.set()

        task = asyncio.create_task(stopper())
        await asyncio.wait_for(service.run(stop), timeout)
        task.cancel()

    asyncio.run(main())
