"""Shared fixtures: the two presets and a few long runs that several tests read."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, is_hypothesis_test, settings

# Property-based tests. "ci" (the default) draws a fixed, reproducible set of a few examples
# (derandomized: the same on every run, so the default run stays short and never flaky);
# "slow" explores many more, randomly (a longer fuzzing run). Tests marked slow get the
# "slow" profile (see pytest_collection_modifyitems below); HYPOTHESIS_PROFILE=slow gives it
# to every property test. A test's own @settings(max_examples=...) overrides the profile's
# count.
settings.register_profile(
    "ci",
    max_examples=12,
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "slow", max_examples=500, deadline=None, print_blob=True, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject.toml's addopts): two workers more than the cores. Many tests wait
    rather than compute (real-time loops of the rig protocol, timeouts, a Ctrl-C's end, the
    processes of a command under test), and two more workers keep the cores busy meanwhile; on a
    machine shared with other work they also keep the run's share of it."""
    return (os.cpu_count() or 1) + 2


def pytest_collection_modifyitems(config, items):
    """Property tests marked slow run with the "slow" profile (unless they set their own)."""
    slow = settings.get_profile("slow")
    for item in items:
        test = getattr(item, "obj", None)
        if item.get_closest_marker("slow") is None or test is None or not is_hypothesis_test(test):
            continue
        if getattr(test, "_hypothesis_internal_settings_applied", False):
            continue  # the test's own @settings (or an earlier item of the same function)
        settings(slow)(test)


# The reference solver lives beside the tests (tests/oracle.py); the benchmarks import
# it the same way.
sys.path.insert(0, str(Path(__file__).resolve().parent))

import drill_env  # noqa: E402

# The library never changes the user's matplotlib backend (it draws what it saves with the
# object-oriented API): the tests run under a backend of their own that no library code would
# pick, and every test checks that it is still the backend when the test ends.
_USERS_BACKEND = "svg"
os.environ["MPLBACKEND"] = _USERS_BACKEND  # subprocesses started by the tests inherit it
if "matplotlib" in sys.modules:  # imported before this file (by a plugin)
    sys.modules["matplotlib"].use(_USERS_BACKEND)


@pytest.fixture(autouse=True)
def _users_matplotlib_backend_unchanged():
    yield
    matplotlib = sys.modules.get("matplotlib")
    if matplotlib is not None:
        assert matplotlib.get_backend().lower() == _USERS_BACKEND, (
            f"the user's matplotlib backend {_USERS_BACKEND!r} was changed to {matplotlib.get_backend()!r}"
        )


@pytest.fixture(scope="session")
def brake() -> drill_env.RigParams:
    return drill_env.load_params("brake")


@pytest.fixture(scope="session")
def no_brake() -> drill_env.RigParams:
    return drill_env.load_params("no_brake")


@pytest.fixture(scope="session")
def brake_2v(brake) -> drill_env.SimulationResult:
    """300 s of the braked rig at 2 V from rest: stick-slip (Fig. 9)."""
    return drill_env.simulate(brake, 2.0, 300.0)


@pytest.fixture(scope="session")
def brake_1v(brake) -> drill_env.SimulationResult:
    """300 s of the braked rig at 1 V from rest: a limit cycle without stick (Fig. 9)."""
    return drill_env.simulate(brake, 1.0, 300.0)


@pytest.fixture(autouse=True)
def _no_user_agents_dir(monkeypatch):
    """A developer's own DRILL_ENV_AGENTS_DIR must not change which policies the tests load."""
    monkeypatch.delenv("DRILL_ENV_AGENTS_DIR", raising=False)
