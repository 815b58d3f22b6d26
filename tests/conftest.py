"""Shared fixtures: the reference data in ../shared (skipped with a clear message if absent)."""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
DATA = SHARED / "data"


#: Tests that stream in real time between processes (simulator, daemon, MAVProxy, a relay) over
#: sockets or ptys.  With pytest-xdist (``--dist loadgroup``, see pyproject.toml) they form one
#: group and so run one at a time, never two flights sharing the machine's two cores; every other
#: test file is a group of its own, so its module fixtures are computed once.
LIVE_TESTS = (
    "tests/e2e/",
    "tests/reliability/",
    "tests/cli/test_cli_demo.py",
    "tests/cli/test_cli_doctor.py",
    "tests/cli/test_cli_replay.py",
    "tests/cli/test_cli_run.py",
    "tests/evaluation/test_replay_engines.py",
    "tests/firmware_sim/test_sim_cli.py",
    "tests/fleet/",
    "tests/firmware_sim/test_sim_live.py",
    "tests/service/test_daemon_e2e.py",
    "tests/service/test_daemon_loop.py",
    "tests/service/test_http_live.py",
)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        try:
            rel = Path(item.path).resolve().relative_to(REPO).as_posix()
        except ValueError:
            continue
        item.add_marker(pytest.mark.xdist_group("live" if rel.startswith(LIVE_TESTS) else rel))


#: Skip reasons of tests whose dependency ``.ci/run`` installs (the extras test, plot, bench, fleet,
#: http; MAVProxy; Chromium): under CI (``CI`` set, as the CI runner sets it) such a skip is a failure —
#: a broken install must not pass as a green run with whole feature areas skipped.  Elsewhere they skip.
_INSTALLED_BY_CI = (
    "could not import",
    "extra is not installed",
    "needs the http extra",
    "selenium is not installed",
    "no Chromium/chromedriver",
    "MAVProxy is not installed",
)


def _ci_requires(reason: str) -> bool:
    return bool(os.environ.get("CI")) and any(m in reason for m in _INSTALLED_BY_CI)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):  # type: ignore[no-untyped-def]
    outcome = yield
    rep = outcome.get_result()
    if rep.skipped and isinstance(rep.longrepr, tuple) and _ci_requires(str(rep.longrepr[2])):
        rep.outcome = "failed"
        rep.longrepr = f"under CI a dependency .ci/run installs is missing: {rep.longrepr[2]}"


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector):  # type: ignore[no-untyped-def]
    outcome = yield
    rep = outcome.get_result()
    if rep.skipped and isinstance(rep.longrepr, tuple) and _ci_requires(str(rep.longrepr[2])):
        rep.outcome = "failed"
        rep.longrepr = f"under CI a dependency .ci/run installs is missing: {rep.longrepr[2]}"


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; skips the test when it is absent."""
    return _require(DATA)


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    return _require(DATA / "broad")


@pytest.fixture(scope="session")
def mavlink_logs_dir() -> Path:
    return _require(DATA / "mavlink_logs")


@pytest.fixture(autouse=True)
def _isolated_mavahrs_logger() -> object:
    """Undo what an in-process ``mavahrs.cli.main([...])`` does to the ``mavahrs`` logger.

    The CLI (rightly, for a program) gives the logger its own handler, a level
    and ``propagate = False``; a later test capturing logs with ``caplog``
    would then see nothing.
    """
    import logging

    logger = logging.getLogger("mavahrs")
    saved = (list(logger.handlers), logger.level, logger.propagate, logger.disabled)
    yield
    logger.handlers[:] = saved[0]
    logger.setLevel(saved[1])
    logger.propagate = saved[2]
    logger.disabled = saved[3]


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


# --------------------------------------------------------------------------- simulator recordings

#: The gyro temperature coefficient configured for the temperature recording, rad/s per °C.
TEMPCO_RAD_S_PER_C = (math.radians(0.03), math.radians(-0.025), math.radians(0.02))


def write_sim_tlog(path: Path, *args: str, imu_changes: dict[str, object] | None = None) -> Path:
    """``python -m firmware_sim --tlog PATH --fast ARGS`` in-process, optionally changing the IMU model."""
    fs_main = pytest.importorskip("firmware_sim.__main__")
    from firmware_sim.endpoint import Endpoint
    from firmware_sim.simulation import Simulation
    from firmware_sim.streamer import write_tlog

    parser = fs_main.build_parser()
    ns = parser.parse_args(["--tlog", str(path), "--fast", "-q", *args])
    sim, ep = fs_main.settings_from_args(ns)
    if imu_changes:
        sim = replace(sim, imu=replace(sim.imu, **imu_changes))
    write_tlog(Endpoint(Simulation(sim), ep), str(path), ns.duration)
    return path


@pytest.fixture(scope="session")
def sim_hover_tlog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s of hover from the simulator: RAW_IMU + a live SCALED_IMU2 at 250 Hz, SIMSTATE truth."""
    return write_sim_tlog(
        tmp_path_factory.mktemp("sim") / "hover.tlog", "--scenario", "hover", "--duration", "20", "--seed", "3"
    )


@pytest.fixture(scope="session")
def sim_gps_raw_tlog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 s of the ``aggressive`` flight with GPS_RAW_INT at 10 Hz (5 Hz fixes, each sent twice) as well."""
    return write_sim_tlog(
        tmp_path_factory.mktemp("sim") / "gps_raw.tlog",
        "--scenario", "aggressive", "--duration", "12", "--seed", "5", "--stream", "GPS_RAW_INT=10",
    )  # fmt: skip


@pytest.fixture(scope="session")
def sim_temperature_tlog(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, tuple[float, float, float]]:
    """The simulator's ``temperature`` scenario (warm-up 10 → 50 °C, τ 40 s) with a known gyro tempco:
    (tlog path, the configured coefficient in rad/s per °C)."""
    path = write_sim_tlog(
        tmp_path_factory.mktemp("sim") / "temperature.tlog",
        "--scenario", "temperature", "--duration", "120", "--seed", "5", "--imus", "1",
        imu_changes={"gyro_temp_coeff_rad_s_per_c": TEMPCO_RAD_S_PER_C},
    )  # fmt: skip
    return path, TEMPCO_RAD_S_PER_C
