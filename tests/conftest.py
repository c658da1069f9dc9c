"""Session-wide simulated scenarios shared by several test modules.

Simulating a paper scenario (a 10 kHz closed-loop cut plus its idling runs) or
the linear machine's air moves is the most expensive setup in the suite, and
several modules need exactly the same data.  The fixtures below build each
once per session and hand out the same objects.

:class:`~drivesense.recording.Recording` objects are immutable (every method
returns a new one), so sharing them is safe; collections of runs are handed
out as tuples.  A test that needs different settings or seeds builds its own.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import pytest

from drivesense.recording import Recording

#: The feed-direction condition most tests use (r = 6 mm, 1000 rpm; Fig. 15 of the first paper).
FEED = "feed_r6_S1000"
#: The cross-feed condition the estimator tests use (r = 6 mm, 4000 rpm).
CROSS = "cross_r6_S4000"


def _skipped(session) -> list:
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    return list(reporter.stats.get("skipped", [])) if reporter is not None else []


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
    return f"{report.nodeid}: {reason.removeprefix('Skipped: ')}"


def pytest_sessionfinish(session, exitstatus):
    """Under ``CI=true`` nothing may skip: a missing browser, broker, database or package fails the run.

    Each test that needs one skips elsewhere (a developer's machine without PostgreSQL); in CI, where
    ``scripts/test`` installs and starts all of them, a skip can only mean a forgotten install step.
    """
    if os.environ.get("CI") == "true" and _skipped(session) and session.exitstatus == 0:
        session.exitstatus = 1


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Say why a run under ``CI=true`` failed on skips."""
    skipped = list(terminalreporter.stats.get("skipped", []))
    if os.environ.get("CI") == "true" and skipped:
        reasons = "; ".join(_skip_reason(r) for r in skipped[:10])
        terminalreporter.write_line(f"CI=true: {len(skipped)} test(s) skipped, and under CI nothing may skip: "
                                    f"{reasons}", red=True, bold=True)


@dataclass(frozen=True)
class Scenario:
    """One paper condition simulated as ``simulate_cut(cond, settings)`` + ``simulate_idle(cond, settings)``.

    Attributes
    ----------
    cond : CutCondition
        The condition (``condition_by_name(name)[0]``).
    cut : Recording
        The cut, ``seed=0``.
    idle : tuple of Recording or None
        Three idling runs over the cut's trajectory (``seed=1000, 1001, 1002``)
        for feed-direction conditions; None for cross-feed ones (tared instead).
    """

    cond: object
    cut: Recording
    idle: tuple[Recording, ...] | None


@functools.cache
def _scenario(name: str, ideal: bool) -> Scenario:
    from drivesense.sim.scenarios import ScenarioSettings, condition_by_name, simulate_cut, simulate_idle

    cond = condition_by_name(name)[0]
    settings = ScenarioSettings().as_ideal() if ideal else ScenarioSettings()
    idle = tuple(simulate_idle(cond, settings)) if cond.direction == "feed" else None
    return Scenario(cond, simulate_cut(cond, settings), idle)


@pytest.fixture(scope="session")
def paper_scenario():
    """Factory ``paper_scenario(name, ideal=False) -> Scenario``, cached for the session.

    ``ideal=True`` uses ``ScenarioSettings().as_ideal()`` (data from exactly the
    estimators' model); the default is the full physics of the Table 1 stage.
    """
    def get(name: str, ideal: bool = False) -> Scenario:
        return _scenario(name, bool(ideal))

    return get


@pytest.fixture(scope="session")
def feed_scenario(paper_scenario) -> Scenario:
    """Full physics, ``feed_r6_S1000``: the cut and its three idling runs."""
    return paper_scenario(FEED)


@pytest.fixture(scope="session")
def linear_air_moves() -> tuple[Recording, ...]:
    """The linear machine's identification air moves, ``simulate_air_moves(seed=7)`` (full physics)."""
    from drivesense.sim.machining import simulate_air_moves

    return tuple(simulate_air_moves(seed=7))


@pytest.fixture()
def mosquitto():
    """A real mosquitto broker on a free loopback port (stopped after the test)."""
    from servers import Mosquitto

    broker = Mosquitto()
    yield broker
    broker.stop()
