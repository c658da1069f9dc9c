"""A local mosquitto broker for tests, benchmarks and trying the monitor out (Debian's ``mosquitto``).

::

    broker = LocalBroker()            # a free loopback port, persistent sessions, its own folder
    broker.url                        # "mqtt://127.0.0.1:PORT"
    broker.restart(down_s=1.0)        # the same port and persistence
    broker.stop()
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from drivesense.errors import ConfigError

__all__ = ["LocalBroker", "free_port", "find_mosquitto"]


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def find_mosquitto() -> str | None:
    """Path of the mosquitto binary (``PATH`` or ``/usr/sbin``), None when it is not installed."""
    found = shutil.which("mosquitto")
    if found:
        return found
    return "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").is_file() else None


class LocalBroker:
    """mosquitto on 127.0.0.1 at a free port, with persistent sessions kept in its own folder.

    Run as root, mosquitto drops to its own user unless told ``user root``; it could not write its
    persistence file then, and a restart would silently lose every queued message.

    Parameters
    ----------
    folder : Path, optional
        Its configuration and persistence folder (default: a new temporary one).
    """

    def __init__(self, folder: str | Path | None = None) -> None:
        binary = find_mosquitto()
        if binary is None:
            raise ConfigError("mosquitto is not installed (Debian: apt-get install mosquitto)")
        self.binary = binary
        self.folder = Path(folder) if folder is not None else Path(tempfile.mkdtemp(prefix="ds-mosquitto-"))
        self.folder.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.conf = self.folder / "mosquitto.conf"
        self.conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence true\n"
                             f"persistence_location {self.folder}/\nmax_queued_messages 100000\nuser root\n")
        self.proc: subprocess.Popen | None = None
        self.start()

    @property
    def url(self) -> str:
        """``mqtt://127.0.0.1:PORT``."""
        return f"mqtt://127.0.0.1:{self.port}"

    def up(self) -> bool:
        """Whether the broker accepts connections."""
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def start(self, timeout: float = 10.0) -> None:
        """Start the broker and wait until it accepts connections.

        Parameters
        ----------
        timeout : float
            Wait at most this long [s].
        """
        self.proc = subprocess.Popen([self.binary, "-c", str(self.conf)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.up():
                return
            time.sleep(0.02)
        raise RuntimeError(f"mosquitto did not start on port {self.port}")

    def stop(self) -> None:
        """Stop the broker (SIGTERM: it saves its persistence file)."""
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc = None

    def restart(self, down_s: float = 0.5) -> None:
        """Stop, wait ``down_s`` [s], start again on the same port.

        Parameters
        ----------
        down_s : float
            Time the broker is away [s].
        """
        self.stop()
        time.sleep(down_s)
        self.start()
