"""Shared fixtures: the reference data in ../shared (skipped with a clear message if absent)."""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
DATA = SHARED / "data"


#: Tests that stream in real time between processes (simulator, daemon, MAVProxy, a relay) over
#: sockets or ptys, the files that take longest first (measured with ``--durations``).  They spend
#: most of their time waiting for a flight, so they are started first, one file per test process
#: (``-n 2``: at most two at a time), and the CPU-bound files fill the time around them.  One unit
#: for all of them would have run ~20 minutes of flights one after the other on a loaded machine.
LIVE_TESTS = (
    "tests/fleet/",
    "tests/reliability/",
    "tests/cli/test_cli_replay.py",
    "tests/service/test_http_live.py",
    "tests/cli/test_cli_demo.py",
    "tests/service/test_daemon_e2e.py",
    "tests/e2e/",
    "tests/cli/test_cli_run.py",
    "tests/replay/test_engine.py",
    "tests/service/test_daemon_loop.py",
    "tests/cli/test_cli_doctor.py",
    "tests/firmware_sim/test_sim_live.py",
    "tests/firmware_sim/test_sim_cli.py",
)


def _live_rank(nodeid: str) -> int:
    """Position of a test's file in :data:`LIVE_TESTS` (``len(LIVE_TESTS)`` for the others)."""
    path = nodeid.split("::", 1)[0]
    return next((i for i, prefix in enumerate(LIVE_TESTS) if path.startswith(prefix)), len(LIVE_TESTS))


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The live files first, longest first; then the rest in their usual order (a stable sort)."""
    items.sort(key=lambda item: _live_rank(item.nodeid))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """``--dist loadgroup``: each test file is a unit of work (its module fixtures computed once), handed
    out in collection order (the live files first), whatever the pytest version.

    xdist's own ``loadgroup`` reads ``xdist_group`` marks by renaming each test's node id (``…@group``),
    which pytest ≥ 9 no longer lets it do (node ids became structured): every test would be a unit of
    its own, and a module fixture computed in both workers.
    """
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    config.option.loadscopereorder = False  # keep the order above (xdist would sort the units by size)

    class _Files(LoadScopeScheduling):  # type: ignore[misc]
        def _split_scope(self, nodeid: str) -> str:
            return nodeid.split("::", 1)[0]

    return _Files(config, log)


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
    "needs setuptools>=77 in the running environment",
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
    _count_off_loopback_attempts(item, call, rep)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector):  # type: ignore[no-untyped-def]
    outcome = yield
    rep = outcome.get_result()
    if rep.skipped and isinstance(rep.longrepr, tuple) and _ci_requires(str(rep.longrepr[2])):
        rep.outcome = "failed"
        rep.longrepr = f"under CI a dependency .ci/run installs is missing: {rep.longrepr[2]}"


# --------------------------------------------------------------------------- loopback only

#: Every test process runs in a network namespace of its own whose only interface is ``lo`` (as root,
#: which CI is: ``unshare(CLONE_NEWNET)`` at start-up; the processes a test starts inherit it).  Nothing
#: can leave the machine from there, and each attempt to reach an address beyond loopback — a connect,
#: a datagram, a DNS query to the configured name server — fails with "network is unreachable" and is
#: counted by the kernel (``OutNoRoutes`` in the namespace's /proc/net/snmp and snmp6).  A test during
#: which that count grows fails, naming the count.  Elsewhere (not root) the tests run on the host's
#: network and ``test_no_network.py`` skips.  MAVAHRS_TESTS_HOST_NETWORK=1 opts out.
_CLONE_NEWNET = 0x40000000
_loopback_ns: dict[str, object] = {}


def _off_loopback_attempts() -> int:
    """Sends/connects to non-loopback addresses that found no route, in this thread's network namespace."""
    with open("/proc/thread-self/net/snmp", encoding="ascii") as f:
        head, values = (line.split() for line in f.read().splitlines()[:2])
    ipv4 = int(values[head.index("OutNoRoutes")])
    ipv6 = 0
    try:
        with open("/proc/thread-self/net/snmp6", encoding="ascii") as f:
            ipv6 = next((int(line.split()[1]) for line in f if line.startswith("Ip6OutNoRoutes")), 0)
    except FileNotFoundError:  # IPv6 disabled
        pass
    return ipv4 + ipv6


def socket_has_ipv6() -> bool:
    return os.path.exists("/proc/thread-self/net/snmp6")


def _bring_up_loopback() -> None:
    import fcntl
    import socket
    import struct

    siocgifflags, siocsifflags, iff_up = 0x8913, 0x8914, 0x1
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        ifreq = fcntl.ioctl(s, siocgifflags, struct.pack("16sH22x", b"lo", 0))
        flags = struct.unpack("16sH22x", ifreq)[1]
        fcntl.ioctl(s, siocsifflags, struct.pack("16sH22x", b"lo", flags | iff_up))


#: Chromium and chromedriver ask whether IPv6 reaches the internet by connecting (without sending on) a
#: UDP socket to this address (Google's public DNS): a blackhole route makes that connect fail without
#: being counted (EINVAL instead of "no route"), and drops anything sent there.
_IPV6_PROBE = "2001:4860:4860::8888"


def _blackhole_route_ipv6(address: str) -> None:
    """``ip -6 route add blackhole ADDRESS/128`` over rtnetlink (no iproute2 needed)."""
    import socket
    import struct

    rtm_newroute, nlm_f_request, nlm_f_ack, nlm_f_create, rtn_blackhole, rta_dst = 24, 1, 4, 0x400, 6, 1
    rtmsg = struct.pack("BBBBBBBBI", socket.AF_INET6, 128, 0, 0, 254, 3, 0, rtn_blackhole, 0)
    attr = struct.pack("HH", 4 + 16, rta_dst) + socket.inet_pton(socket.AF_INET6, address)
    body = rtmsg + attr
    msg = struct.pack("IHHII", 16 + len(body), rtm_newroute, nlm_f_request | nlm_f_ack | nlm_f_create, 1, 0) + body
    with socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, socket.NETLINK_ROUTE) as nl:
        nl.settimeout(10)
        nl.send(msg)
        reply = nl.recv(4096)
    error = struct.unpack_from("i", reply, 16)[0]
    if error:
        raise OSError(-error, os.strerror(-error))


def _enter_loopback_only_network() -> str | None:
    """Move this thread into a new network namespace with ``lo`` up; None if done, else why not."""
    if os.environ.get("MAVAHRS_TESTS_HOST_NETWORK"):
        return "MAVAHRS_TESTS_HOST_NETWORK is set"
    if not sys.platform.startswith("linux"):
        return "network namespaces are Linux's"
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    host = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    if libc.unshare(_CLONE_NEWNET) != 0:
        os.close(host)
        return f"unshare(CLONE_NEWNET): {os.strerror(ctypes.get_errno())} (needs root or CAP_SYS_ADMIN)"
    try:
        _bring_up_loopback()
        if socket_has_ipv6():
            _blackhole_route_ipv6(_IPV6_PROBE)
    except OSError as exc:
        libc.setns(host, _CLONE_NEWNET)
        os.close(host)
        return f"could not bring up lo in a new network namespace: {exc}"
    os.close(host)
    _loopback_ns["ns"] = os.readlink("/proc/thread-self/ns/net")
    _loopback_ns["fd"] = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    return None


@pytest.fixture
def off_loopback_attempts() -> object:
    """The kernel's count of attempts to reach beyond loopback (a callable); skips the test when the
    tests run on the host's network."""
    if "ns" not in _loopback_ns:
        pytest.skip(f"tests run on the host's network here: {_loopback_ns.get('skip')}")
    return _off_loopback_attempts


def pytest_sessionstart(session: pytest.Session) -> None:
    why_not = _enter_loopback_only_network()
    if why_not is not None:
        _loopback_ns["skip"] = why_not
    _warm_up_kernels(session.config)


def _warm_up_kernels(config: pytest.Config) -> None:
    """``mavahrs warm-up`` once, before the test processes start, when the suite runs on several of them.

    On a cold numba cache (a fresh clone, an edited filter) each worker would otherwise compile the same
    kernels at the same time, and so would the daemons and replays the live tests start — inside their
    deadlines, on a machine already busy compiling.  Compiled once here (about a minute on a cold cache,
    a few seconds to load a warm one), every later process loads them from the cache (``NUMBA_CACHE_DIR``
    or ``mavahrs/filters/__pycache__``, as the tests' own processes use).  Runs in the controlling
    process only (not in xdist's workers); ``MAVAHRS_TESTS_WARM_UP=1`` also for ``-n 0``, ``=0`` never.
    """
    import subprocess

    wanted = os.environ.get("MAVAHRS_TESTS_WARM_UP")
    if wanted == "0" or hasattr(config, "workerinput"):
        return
    workers = config.getoption("numprocesses", default=None) if config.pluginmanager.has_plugin("xdist") else None
    if wanted != "1" and not workers:
        return
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    try:
        done = subprocess.run([sys.executable, "-m", "mavahrs", "warm-up"], env=env, cwd=REPO, timeout=1800,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    except (OSError, subprocess.TimeoutExpired) as exc:  # the tests that need the kernels will say more
        sys.stderr.write(f"tests/conftest.py: mavahrs warm-up failed before the tests: {exc}\n")
        return
    if done.returncode != 0:
        sys.stderr.write(f"tests/conftest.py: mavahrs warm-up exited {done.returncode}:\n{done.stdout[-3000:]}\n")


def pytest_runtest_logstart(nodeid: str, location: tuple[str, int | None, str]) -> None:
    if "ns" not in _loopback_ns:
        return
    if os.readlink("/proc/thread-self/ns/net") != _loopback_ns["ns"]:  # a runner thread other than the first
        import ctypes

        ctypes.CDLL(None, use_errno=True).setns(_loopback_ns["fd"], _CLONE_NEWNET)
    _loopback_ns["before"] = _off_loopback_attempts()


def _count_off_loopback_attempts(item: pytest.Item, call: pytest.CallInfo[None], rep: pytest.TestReport) -> None:
    if call.when != "teardown" or "before" not in _loopback_ns:
        return
    attempts = _off_loopback_attempts() - int(_loopback_ns.pop("before"))  # type: ignore[call-overload]
    if attempts > 0 and item.get_closest_marker("reaches_off_loopback") is None:
        rep.outcome = "failed"
        rep.longrepr = (f"{attempts} attempt(s) to reach an address beyond loopback during this test (a connect, "
                        "a datagram or a DNS query; tests must touch loopback only; tests/conftest.py)")


def pytest_configure(config: pytest.Config) -> None:
    # A suite started in the background by a shell without job control (`nohup … &` in a script,
    # `( … & )`) inherits SIGINT ignored, and every process it starts then ignores Ctrl-C too: the
    # tests that interrupt a real `mavahrs` command would see it run to the end.  Python's own
    # handler is installed here (the xdist workers, started after this hook, and the commands the
    # tests start inherit the default action instead of "ignored").
    import signal

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    config.addinivalue_line("markers", "reaches_off_loopback: the test tries to reach beyond loopback on purpose "
                            "(it checks the check); exempt from the per-test count")


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; skips the test when it is absent."""
    return _require(DATA)


@pytest.fixture(scope="session")
def shared_file() -> Callable[[str], Path]:
    """``shared_file("sitl/arducopter_onboard.BIN")``: that file under ``../shared/data``; the test skips, saying
    where it looked, when the file is absent."""
    return lambda rel: _require(DATA / rel)


@pytest.fixture(scope="session")
def sitl_gentle_tlog() -> Path:
    """``../shared/data/sitl/arducopter_gentle.tlog`` (the shortest ArduCopter SITL flight, 59 s); skips when absent."""
    return _require(DATA / "sitl" / "arducopter_gentle.tlog")


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


# --------------------------------------------------------------------------- a stand-in pipeline for the daemon


class HeartbeatOnlyPipeline:
    """The daemon's pipeline interface, handling nothing: our HEARTBEAT (1/191, onboard controller) every tick.

    For tests of what the daemon itself does around the pipeline (requests addressed to component 191,
    answered by ``mavahrs.service.component``): its codec is the real one with our ids.
    ``heartbeat_to_master``: the HEARTBEAT also goes on the master link (so a ``udpin`` peer there learns
    where we are), not only to the ``--out`` outputs.
    """

    def __init__(self, heartbeat_to_master: bool = True) -> None:
        from mavahrs.protocol.codec import MavCodec

        self.codec = MavCodec(1, 191)
        self.heartbeat_to_master = heartbeat_to_master

    def handle(self, msg: object, now_us: int) -> list[object]:
        return []

    def tick(self, now_us: int) -> list[object]:
        from mavahrs.service.pipeline import Outgoing

        frame = self.codec.encode(self.codec.mav.heartbeat_encode(18, 8, 0, 0, 4))  # MAV_TYPE_ONBOARD_CONTROLLER
        return [Outgoing(frame, self.heartbeat_to_master, True)]

    def status(self, now_us: int | None = None) -> dict[str, object]:
        return {"input_rate_hz": 0.0, "drops": {}}

    def drain_notices(self) -> list[tuple[int, str]]:
        return []

    def reset_link(self, now_us: int) -> None:
        pass


@pytest.fixture
def heartbeat_only_pipeline() -> type[HeartbeatOnlyPipeline]:
    """:class:`HeartbeatOnlyPipeline`, for test modules (``--import-mode=importlib``: no ``from conftest import``)."""
    return HeartbeatOnlyPipeline


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
def sim_tlog_writer() -> Callable[..., Path]:
    """:func:`write_sim_tlog`, for test modules (``--import-mode=importlib``: no ``from conftest import``)."""
    return write_sim_tlog


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


# --------------------------------------------------------------------------- DataFlash logs written here

#: DataFlash format character → struct code (ArduPilot's LogStructure.h; pymavlink's DFReader.FORMAT_TO_STRUCT)
_DF_STRUCT = {"a": "32h", "b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
              "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "B",
              "q": "q", "Q": "Q"}  # fmt: skip
#: ArduPilot 4.5's formats of the messages the DataFlash reader takes (names and format characters as logged)
DF_FORMATS = {
    "IMU": (129, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "MAG": (130, "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"),
    "PARM": (131, "QNff", "TimeUS,Name,Value,Default"),
    "SIM": (132, "QccCfLLffff", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng,Q1,Q2,Q3,Q4"),
    "XKQ": (133, "QBffff", "TimeUS,C,Q1,Q2,Q3,Q4"),
    "BAT": (134, "QBfffffcfBBB", "TimeUS,Inst,Volt,VoltR,Curr,CurrTot,EnrgTot,Temp,Res,RemPct,H,SH"),
    "VIBE": (135, "QBfffI", "TimeUS,IMU,VibeX,VibeY,VibeZ,Clip"),
}


class DataflashWriter:
    """DataFlash records as ArduPilot writes them: ``A3 95 type payload``, each type announced by a FMT."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.types: dict[str, tuple[int, str]] = {}
        self.fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def fmt(self, type_id: int, name: str, fmt: str, cols: str) -> None:
        import struct

        length = 3 + struct.calcsize("<" + "".join(_DF_STRUCT.get(c, "B") for c in fmt))
        self.buf += b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(),
                                                  cols.encode())  # fmt: skip
        self.types[name] = (type_id, fmt)

    def rec(self, name: str, *values: object) -> None:
        import struct

        type_id, fmt = self.types[name]
        self.buf += b"\xa3\x95" + bytes([type_id]) + struct.pack("<" + "".join(_DF_STRUCT[c] for c in fmt), *values)


def synthetic_flight(duration_s: float = 20.0, rate_hz: float = 400.0) -> dict[str, np.ndarray]:
    """A rotating, tilting vehicle at the IMU rate: body rates, true q_body_to_ned, specific force, field.

    The attitude is the exact integral of the body rates, so the IMU and the truth agree to float precision.
    """
    from mavahrs.geometry import quaternion as quat

    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    w = 2.0 * math.pi / 6.0
    gyro = np.stack([0.4 * np.sin(w * t), 0.3 * np.cos(1.3 * w * t), np.full(n, 0.15)], axis=1)
    gyro[t < 3.0] = 0.0  # at rest for the first 3 s (the filters start from the accelerometer and compass)
    q = np.empty((n, 4))
    q[0] = (1.0, 0.0, 0.0, 0.0)
    for k in range(1, n):
        q[k] = quat.normalize(quat.multiply(q[k - 1], quat.from_rotation_vector(gyro[k - 1] / rate_hz)))
    qc = quat.conjugate(q)
    accel = quat.rotate(qc, np.tile([0.0, 0.0, -9.80665], (n, 1)))
    mag_ut = quat.rotate(qc, np.tile([22.0, 0.0, 42.0], (n, 1)))  # no declination: magnetic north = true north
    return {"t_s": t, "gyro_rad_s": gyro, "accel_m_s2": accel, "mag_ut": mag_ut, "q_body_to_ned": q}


def write_dataflash(
    path: Path,
    *,
    duration_s: float = 20.0,
    t0_us: int = 5_000_000,
    imus: int = 2,
    params: dict[str, float] | None = None,
    extra: Callable[[DataflashWriter], None] | None = None,
    gyro_noise_rad_s: float = 0.0,
) -> tuple[Path, dict[str, np.ndarray]]:
    """A 400 Hz ArduCopter-like DataFlash log of :func:`synthetic_flight`: IMU ×``imus``, MAG 10 Hz,
    SIM truth and XKQ at 25 Hz (XKQ = the truth), BAT/VIBE at 10 Hz, PARM first; ``extra`` may add records
    before the flight's (a newer firmware's messages); ``gyro_noise_rad_s``: white noise (SD, seeded) on the
    logged gyro. Returns the path and the flight (with ``TimeUS``)."""
    from mavahrs.geometry.rotation import to_euler_rad

    fl = synthetic_flight(duration_s)
    tus = t0_us + np.round(fl["t_s"] * 1e6).astype(np.int64)
    fl["TimeUS"] = tus
    if gyro_noise_rad_s:
        fl["gyro_rad_s"] = fl["gyro_rad_s"] + np.random.default_rng(5).normal(0.0, gyro_noise_rad_s, (tus.size, 3))
    w = DataflashWriter()
    for name, (tid, fmt, cols) in DF_FORMATS.items():
        w.fmt(tid, name, fmt, cols)
    if extra is not None:
        extra(w)
    p = {"INS_GYRO_FILTER": 20.0, "SCHED_LOOP_RATE": 400.0, "COMPASS_DEC": 0.0, "AHRS_EKF_TYPE": 3.0}
    p.update(params or {})
    for k, v in p.items():
        w.rec("PARM", int(t0_us - 1000), k.encode(), float(v), float(v))
    eul = np.degrees(to_euler_rad(fl["q_body_to_ned"]))
    for k in range(tus.shape[0]):
        t = int(tus[k])
        g, a = fl["gyro_rad_s"][k], fl["accel_m_s2"][k]
        for i in range(imus):
            w.rec("IMU", t + 20 * i, i, *g.tolist(), *a.tolist(), 0, 0, 25.0, 1, 1, 400, 400)
        if k % 40 == 0:
            m = np.round(fl["mag_ut"][k] * 10.0).astype(int).tolist()
            w.rec("MAG", t + 50, 0, *m, 0, 0, 0, 0, 0, 0, 1, t + 50)
            w.rec("BAT", t + 60, 0, 16.0 - 1e-5 * k, 16.0, 12.5, 0.0, 0.0, 2500, 0.01, 90, 1, 0)
            w.rec("VIBE", t + 70, 0, 3.0, 3.5, 4.0, 0)
        if k % 16 == 0:
            qk = fl["q_body_to_ned"][k]
            r, pch, y = eul[k]
            w.rec("SIM", t, int(round(r * 100)), int(round(pch * 100)), int(round((y % 360.0) * 100)),
                  100.0, 0, 0, *qk.tolist())  # fmt: skip
            w.rec("XKQ", t + 10, 0, *qk.tolist())
    path.write_bytes(bytes(w.buf))
    return path, fl


@pytest.fixture(scope="session")
def dataflash_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    """20 s of :func:`write_dataflash`'s synthetic 400 Hz flight, two IMUs (session-wide, written once)."""
    return write_dataflash(tmp_path_factory.mktemp("df") / "synthetic.BIN")


@pytest.fixture
def write_df() -> Callable[..., tuple[Path, dict[str, np.ndarray]]]:
    """:func:`write_dataflash`, for tests that write a DataFlash log of their own."""
    return write_dataflash


@pytest.fixture
def df_writer() -> type[DataflashWriter]:
    """:class:`DataflashWriter`, for hand-built DataFlash bytes."""
    return DataflashWriter


@pytest.fixture
def interrupt_replay(monkeypatch: pytest.MonkeyPatch) -> Callable[[int], None]:
    """``interrupt_replay(n)``: from then on the fast replay engine filters blocks of 1000 samples and raises
    KeyboardInterrupt (as Ctrl-C does) in its ``n``-th per-filter block step, after ``n − 1`` blocks."""

    def arm(n: int = 3) -> None:
        import mavahrs.replay.engine as engine  # the module whose globals the engine reads

        monkeypatch.setattr(engine, "_CHUNK", 1000)
        calls = [0]
        real = engine._out_rate

        def interrupt_at_block(*args: object) -> None:
            calls[0] += 1
            if calls[0] == n:
                raise KeyboardInterrupt
            real(*args)

        monkeypatch.setattr(engine, "_out_rate", interrupt_at_block)

    return arm


def _load_script(name: str) -> ModuleType:
    """``scripts/NAME.py`` as a module (imported once per process, under its own name)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def bench_script() -> Callable[[str], ModuleType]:
    """``bench_script("bench_monitor")``: a script of ``scripts/`` as a module, for tests of its functions."""
    return _load_script

