"""Shared test helpers: where the real recordings are, and loud skipping when they are absent;
the check that a bad input is refused in one line; a short prepared flight for the window
engine's tests.

The recordings live in ``../shared/data`` next to the repository (never copied into it). Tests
that need them use :func:`shared_data`: without the folder they skip, and the session summary
says how many did; with ``CI=true`` a missing folder fails them instead, because CI has it.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import pytest

from mocap_calib.core.prepare.session import local_derivative, prepare
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, simulate_flight

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
#: How a missing recording's skip reason reads; the summary finds those skips by it.
_MISSING = re.compile(r"real recording (.+?) is missing \(expected ../shared/data")


def shared_data(*parts: str) -> Path:
    """Path under ``../shared/data``; skip (or fail under CI) when it is missing."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        msg = f"real recording {path} is missing (expected ../shared/data next to the repo)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(msg)
        pytest.skip(msg)
    return path


def _skip_reason(report: pytest.TestReport) -> str:
    # A skip's longrepr is (path, line, reason); xdist sends it to the controller as a list.
    lr = report.longrepr
    return str(lr[2]) if isinstance(lr, (tuple, list)) and len(lr) == 3 else str(lr)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    # From the reports the terminal collected, not from a list filled while tests run: under
    # pytest-xdist the tests run in worker processes and only their reports reach this one.
    missing = [m.group(1) for rep in terminalreporter.stats.get("skipped", [])
               if (m := _MISSING.search(_skip_reason(rep)))]
    if missing:
        terminalreporter.write_sep("!", f"{len(missing)} real-data tests SKIPPED, missing: "
                                        f"{', '.join(sorted(set(missing)))}", red=True, bold=True)


@pytest.fixture
def euroc_dir() -> Path:
    """``../shared/data/euroc_V2_03_difficult`` (holds ``mav0``)."""
    return shared_data("euroc_V2_03_difficult", "mav0").parent


@pytest.fixture
def broad21_csv() -> Path:
    """BROAD trial 21's one-file CSV."""
    return shared_data("broad_21_undisturbed_fast_combined", "data.csv")


def refused(fn: Callable[[], object], *parts: str) -> str:
    """Call ``fn``; it must raise a one-line InputError containing every part (returned)."""
    with pytest.raises(InputError) as err:
        fn()
    msg = str(err.value)
    assert "\n" not in msg
    for part in parts:
        assert part in msg, f"{part!r} not in {msg!r}"
    return msg


@pytest.fixture(scope="module")
def short_session():
    """A 12 s simulated flight (seed 11, a 3 ms clock offset) prepared, with the mocap
    velocities the windows start from: (simulation, session, velocities)."""
    sim = simulate_flight(SimConfig(seed=11, duration=12.0, effects={"time_offset": [0.003]}))
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    return sim, s, v
