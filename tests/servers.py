"""Real servers the service tests run against: Debian's mosquitto on a free loopback port.

``scripts/test`` installs mosquitto (and chromium); with ``CI=true`` a missing binary fails the test instead
of skipping it.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

__all__ = ["Mosquitto", "free_port", "require_binary"]


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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


class Mosquitto:
    """A mosquitto broker on 127.0.0.1 at a free port; ``restart()`` keeps the port (and persistence)."""

    def __init__(self) -> None:
        self.binary = require_binary("mosquitto", "/usr/sbin/mosquitto")
        self.port = free_port()
        self.dir = Path(tempfile.mkdtemp(prefix="ds-mosquitto-"))
        self.dir.chmod(0o777)                  # run as root, mosquitto drops to its own user: it must write here
        (self.dir / "mosquitto.conf").write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence true\n"
            f"persistence_location {self.dir}/\nmax_queued_messages 100000\n")
        self.proc: subprocess.Popen | None = None
        self.start()

    @property
    def url(self) -> str:
        """``mqtt://127.0.0.1:PORT``."""
        return f"mqtt://127.0.0.1:{self.port}"

    def start(self) -> None:
        """Start the broker and wait until it accepts connections."""
        self.proc = subprocess.Popen([self.binary, "-c", str(self.dir / "mosquitto.conf")],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 10
        while time.time() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not start")

    def stop(self) -> None:
        """Stop the broker (SIGTERM: it saves its persistence file)."""
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(10)
            self.proc = None

    def restart(self, down_s: float = 0.5) -> None:
        """Stop, wait ``down_s`` [s], start again on the same port."""
        self.stop()
        time.sleep(down_s)
        self.start()
