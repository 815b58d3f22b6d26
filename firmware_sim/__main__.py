r"""``python -m firmware_sim`` / ``mavahrs-sim``: a simulated flight controller.

Examples::

    python -m firmware_sim --out udpout:127.0.0.1:14550 --scenario aggressive --duration 60 --seed 1
    python -m firmware_sim --out pty --scenario hover --duration 0          # prints "PTY /dev/pts/N"
    python -m firmware_sim --tlog aggressive.tlog --fast --scenario aggressive --duration 60

Exit codes: 0 done (also after SIGINT/SIGTERM), 1 unexpected error,
2 bad arguments, 3 the link could not be opened.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
from collections.abc import Sequence
from dataclasses import replace

from firmware_sim.endpoint import STREAMABLE, Endpoint, EndpointSettings
from firmware_sim.imu_model import EarthField, ImuErrorSettings, MagSettings
from firmware_sim.simulation import (
    AttitudeFault,
    CurrentSettings,
    Home,
    ImuFault,
    MagAnomaly,
    SimSettings,
    Simulation,
)
from firmware_sim.streamer import (
    Blackout,
    describe_link,
    open_link,
    run_realtime,
    write_stats_json,
    write_tlog,
)
from firmware_sim.trajectory import SCENARIO_DESCRIPTIONS, SCENARIOS
from mavahrs.errors import ConfigError, TransportError

__all__ = ["main", "build_parser", "settings_from_args"]

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_LINK = 0, 1, 2, 3
log = logging.getLogger("firmware_sim")


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n:
        raise argparse.ArgumentTypeError(f"{what}: expected {n} comma-separated numbers, got {len(vals)}")
    return vals


def _stream(text: str) -> tuple[str, float]:
    name, sep, hz = text.partition("=")
    name = name.strip().upper()
    if not sep or name not in STREAMABLE:
        raise argparse.ArgumentTypeError(f"--stream NAME=HZ with NAME one of {', '.join(STREAMABLE)}; got {text!r}")
    if hz.strip().lower() == "max":
        return name, math.inf
    try:
        return name, float(hz)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--stream {name}: rate must be a number of Hz or 'max'") from None


def _blackout(text: str) -> Blackout:
    vals = _floats(text.replace(":", ","), 2, "--blackout START:DURATION")
    return Blackout(vals[0], vals[1])


def _imu_fault(text: str) -> ImuFault:
    """``imuN:gyro_bias_dps=V[,V,V]:accel_bias_m_s2=V[,V,V]:at=S`` → :class:`ImuFault`."""
    usage = "--imu-fault imuN:gyro_bias_dps=V[,V,V][:accel_bias_m_s2=V[,V,V]]:at=S"
    head, *parts = text.replace(" ", "").split(":")
    if not (head.lower().startswith("imu") and head[3:].isdigit() and int(head[3:]) <= 2):
        raise argparse.ArgumentTypeError(f"{usage}: expected imu0, imu1 or imu2 first, got {head!r}")
    vals: dict[str, str] = {}
    for part in parts:
        key, sep, value = part.partition("=")
        if not sep or key not in ("gyro_bias_dps", "accel_bias_m_s2", "at"):
            raise argparse.ArgumentTypeError(f"{usage}: unknown item {part!r}")
        vals[key] = value

    def vec(key: str) -> tuple[float, float, float]:
        if key not in vals:
            return (0.0, 0.0, 0.0)
        v = _floats(vals[key], len(vals[key].split(",")), f"--imu-fault {key}")
        if len(v) == 1:
            return (v[0], v[0], v[0])  # one number: every axis
        if len(v) != 3:
            raise argparse.ArgumentTypeError(f"--imu-fault {key}: one number or three (x,y,z)")
        return (v[0], v[1], v[2])

    if "at" not in vals or not ({"gyro_bias_dps", "accel_bias_m_s2"} & set(vals)):
        raise argparse.ArgumentTypeError(f"{usage}: needs a bias and at=S")
    try:
        at = float(vals["at"])
        g = tuple(math.radians(v) for v in vec("gyro_bias_dps"))
        return ImuFault(instance=int(head[3:]), step_at_s=at, gyro_bias_step_rad_s=g,  # type: ignore[arg-type]
                        accel_bias_step_m_s2=vec("accel_bias_m_s2"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--imu-fault: {exc}") from None


def build_parser() -> argparse.ArgumentParser:
    scen = "\n".join(f"  {n:12s} {SCENARIO_DESCRIPTIONS[n]}" for n in SCENARIOS)
    p = argparse.ArgumentParser(
        prog="mavahrs-sim",
        description="Simulated ArduPilot/PX4 flight controller streaming MAVLink IMU data with known true attitude.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"scenarios:\n{scen}\n\nexit codes: 0 done, 1 error, 2 bad arguments, 3 link could not be opened",
    )
    io = p.add_argument_group("output")
    io.add_argument("--out", default="udpout:127.0.0.1:14550", metavar="CONN",
                    help="udpout:HOST:PORT, udpin:HOST:PORT, tcpin:HOST:PORT, a serial path, pty or pty:LINK "
                         "(default %(default)s)")
    io.add_argument("--baud", type=int, default=None, metavar="BIT_S",
                    help="serial baud rate, bit/s; a serial link (and a pty if given) then carries at most "
                         "baud/10 bytes/s, frames that do not fit are deferred as ArduPilot does (default 115200 "
                         "for serial, unlimited for pty)")
    io.add_argument("--tlog", metavar="FILE", help="write a tlog (with --fast: instead of a link; else: record the session)")
    io.add_argument("--fast", action="store_true", help="with --tlog: run as fast as possible, no link")
    io.add_argument("--stats-json", metavar="FILE", help="write counters (received, ACKed, sent, pacing) at exit")
    io.add_argument("--blackout", type=_blackout, action="append", default=[], metavar="START:DURATION",
                    help="link outage in simulation seconds (repeatable)")

    fl = p.add_argument_group("flight")
    fl.add_argument("--scenario", choices=SCENARIOS, default="hover", help="(default %(default)s)")
    fl.add_argument("--duration", type=float, default=60.0, metavar="S",
                    help="simulated seconds; 0 = until stopped (live only) (default %(default)s)")
    fl.add_argument("--seed", type=int, default=0, metavar="N",
                    help="same seed, same flight and bytes (default %(default)s)")
    fl.add_argument("--lat", type=float, default=Home.lat_deg, metavar="DEG", help="home latitude, deg (default %(default)s, CMAC)")
    fl.add_argument("--lon", type=float, default=Home.lon_deg, metavar="DEG", help="home longitude, deg (default %(default)s)")
    fl.add_argument("--alt-m", type=float, default=Home.alt_m, metavar="M", help="home altitude AMSL, m (default %(default)s)")
    fl.add_argument("--start-in-motion", action="store_true",
                    help="no rest period: flying from t=0 (rotors spinning, vibration, 10 m up, 2-5 m/s), "
                         "manoeuvres at once; not with --scenario rest")
    fl.add_argument("--boot-offset-s", type=float, default=0.0, metavar="S", help="time since boot at start, s (default 0)")

    ap = p.add_argument_group("autopilot")
    ap.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot", help="(default %(default)s)")
    ap.add_argument("--sysid", type=int, default=1, metavar="N", help="MAVLink system id (default %(default)s)")
    ap.add_argument("--compid", type=int, default=1, metavar="N", help="MAVLink component id (default %(default)s)")
    ap.add_argument("--loop-rate", type=float, default=400.0, metavar="HZ",
                    help="scheduler loop (SCHED_LOOP_RATE), Hz; the fastest stream ArduPilot accepts is "
                         "1/(ceil(loop period/0.8 ms) ms): 250 Hz at 400, 500 Hz at 800 (default %(default)s)")
    ap.add_argument("--oversample", type=int, default=3, metavar="N",
                    help="sensor samples per loop tick: sensor rate = loop rate x N (default %(default)s)")
    ap.add_argument("--ideal", action="store_true",
                    help="idealised stream: sample-time stamps, no jitter, intervals down to one loop period")
    ap.add_argument("--preset", choices=("default", "bench", "none"), default=None,
                    help="initial stream rates: the autopilot's defaults, 'bench' (IMUs at max + truth), or "
                         "HEARTBEAT only (default: 'default' live, 'bench' with --fast)")
    ap.add_argument("--stream", type=_stream, action="append", default=[], metavar="NAME=HZ",
                    help=f"initial rate of a stream, Hz or 'max' (repeatable); NAME in {', '.join(STREAMABLE)}")
    ap.add_argument("--default-stream-hz", type=float, default=1.0, metavar="HZ",
                    help="ArduPilot SRn_* rate of the default stream groups, Hz (default %(default)s)")
    ap.add_argument("--no-message-interval", action="store_true",
                    help="old firmware: ACK SET_MESSAGE_INTERVAL as UNSUPPORTED")
    ap.add_argument("--attitude-fault", metavar="START[,DUR[,ROLL[,PITCH[,YAW]]]]",
                    help="offset the autopilot's ATTITUDE estimate from START s for DUR s (default inf) by "
                         "ROLL/PITCH/YAW deg (default 10,0,0), ramped over 1 s")

    se = p.add_argument_group("sensors")
    se.add_argument("--imus", type=int, default=2, choices=(1, 2, 3), help="IMU count (default %(default)s)")
    se.add_argument("--mags", type=int, default=2, choices=(0, 1, 2, 3), help="compass count (default %(default)s)")
    se.add_argument("--imu-preset", choices=("calibrated", "raw"), default="calibrated",
                    help="'calibrated': an autopilot's IMU after its boot calibration (residual gyro bias 0.1 deg/s "
                         "sigma); 'raw': an uncalibrated MEMS IMU as a research rig streams it, every IMU message "
                         "(RAW_IMU, SCALED_IMU*, HIGHRES_IMU) carrying it: turn-on gyro bias uniform in +-5 deg/s "
                         "per axis from the seed, accel bias 0.1 m/s2 sigma, scale 0.5%% (default %(default)s)")
    se.add_argument("--gyro-bias-dps", type=lambda t: _floats(t, 3, "--gyro-bias-dps"), metavar="X,Y,Z",
                    help="constant gyro bias of every IMU, deg/s per sensor axis (replaces the drawn one; the "
                         "bias random walk stays unless --noiseless)")
    se.add_argument("--imu-mount-deg", type=lambda t: _floats(t, 3, "--imu-mount-deg"), metavar="ROLL,PITCH,YAW",
                    default=(0.0, 0.0, 0.0),
                    help="sensor board mounting, deg (Z-Y-X Euler rotating the body axes onto the IMU's): IMUs and "
                         "compasses measure in the IMU axes; 0,90,0 = IMU x axis up; the truth stays the body's "
                         "(default 0,0,0)")
    se.add_argument("--imu-fault", type=_imu_fault, metavar="imuN:gyro_bias_dps=V[,V,V]:at=S",
                    help="bias step on one IMU from S s (imu1 = SCALED_IMU2): gyro deg/s and/or "
                         "accel_bias_m_s2=V[,V,V] m/s2, one number = every axis; e.g. imu1:gyro_bias_dps=2:at=30")
    se.add_argument("--imu2-freeze-at", type=float, metavar="S", help="second IMU (SCALED_IMU2) sticks from S s")
    se.add_argument("--imu2-saturate-at", type=float, metavar="S", help="second IMU reads full scale from S s")
    se.add_argument("--no-sensor-errors", action="store_true",
                    help="perfect IMU and compass (no noise, bias, scale, quantisation, vibration; low-pass kept)")
    se.add_argument("--noiseless", action="store_true",
                    help="no sensor noise, bias random walk or vibration (biases, scale, quantisation kept): "
                         "steady states repeat the same whole mG and mrad/s, as ArduPilot's SITL")
    se.add_argument("--gyro-lowpass-hz", type=float, default=None, metavar="HZ",
                    help=f"INS_GYRO_FILTER, Hz; 0 = off (default {ImuErrorSettings.gyro_lowpass_hz:g}; with --autopilot "
                         "px4 0: PX4's HIGHRES_IMU/SCALED_IMU are vehicle_imu's interval mean, not low-passed)")
    se.add_argument("--accel-lowpass-hz", type=float, default=None, metavar="HZ",
                    help=f"INS_ACCEL_FILTER, Hz; 0 = off (default {ImuErrorSettings.accel_lowpass_hz:g}; px4: 0)")
    se.add_argument("--field-ut", type=float, default=EarthField.strength_ut, metavar="UT",
                    help="earth field strength, uT (default %(default)s, WMM2025 at CMAC)")
    se.add_argument("--inclination-deg", type=float, default=EarthField.inclination_deg, metavar="DEG",
                    help="field inclination, deg, + down (default %(default)s)")
    se.add_argument("--declination-deg", type=float, default=EarthField.declination_deg, metavar="DEG",
                    help="magnetic north east of true north, deg (default %(default)s)")
    se.add_argument("--mag-hard-iron-ut", type=lambda t: _floats(t, 3, "--mag-hard-iron-ut"), metavar="X,Y,Z",
                    help="compass offset, body axes, uT (default 0,0,0: calibrated)")
    se.add_argument("--mag-anomaly-ut", type=lambda t: _floats(t, 3, "--mag-anomaly-ut"), metavar="N,E,D",
                    help="ground-level field anomaly at take-off, NED, uT (SIM_MAG_ALY, which is in mGauss = 0.1 uT; "
                         "default: the scenario's, 8,-6,12 for mag_anomaly, none otherwise)")
    se.add_argument("--mag-anomaly-height-m", type=float, metavar="M",
                    help="height above ground where the anomaly has decayed to 1/8, m (SIM_MAG_ALY_HGT; "
                         "default: the scenario's, 5 for mag_anomaly, else 1)")
    se.add_argument("--mag-motor-ut-per-a", type=lambda t: _floats(t, 3, "--mag-motor-ut-per-a"), metavar="X,Y,Z",
                    help="body-frame compass interference per amp of battery current, uT/A (SIM_MAG_MOT, mGauss/A "
                         "there; default: the scenario's, 0.4,-0.3,0.8 for mag_anomaly, none otherwise)")
    se.add_argument("--hover-current-a", type=float, default=CurrentSettings.hover_a, metavar="A",
                    help="battery current in hover, A; scales as (thrust/g)^1.5, reported in SYS_STATUS and "
                         "BATTERY_STATUS (default %(default)s)")
    se.add_argument("--no-gnss", action="store_true",
                    help="no GNSS receiver: GPS_RAW_INT and GLOBAL_POSITION_INT are never sent")
    se.add_argument("--mag-soft-iron", type=lambda t: _floats(t, 9, "--mag-soft-iron"), metavar="M11,...,M33",
                    help="soft-iron 3x3 matrix, row-major (default identity)")

    p.add_argument("--jit", action="store_true",
                   help="compile the physics with numba (always on with --fast; costs ~2 s at start)")
    p.add_argument("--list-scenarios", action="store_true", help="print the scenarios and exit")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings only (no start/stop/status lines)")
    return p


def settings_from_args(args: argparse.Namespace) -> tuple[SimSettings, EndpointSettings]:
    """Build the simulator and endpoint settings from parsed arguments (raises ValueError)."""
    if args.no_sensor_errors and args.imu_preset == "raw":
        raise ValueError("--no-sensor-errors and --imu-preset raw exclude each other")
    imu = ImuErrorSettings.ideal(lowpass=True) if args.no_sensor_errors else (
        ImuErrorSettings.raw() if args.imu_preset == "raw" else ImuErrorSettings())
    if args.gyro_bias_dps is not None:
        imu = replace(imu, gyro_bias_rad_s=tuple(math.radians(v) for v in args.gyro_bias_dps))
    imu = replace(imu, gyro_lowpass_hz=ImuErrorSettings.gyro_lowpass_hz, accel_lowpass_hz=ImuErrorSettings.accel_lowpass_hz)
    mag = MagSettings.ideal() if args.no_sensor_errors else MagSettings()
    if args.noiseless:
        imu, mag = imu.noiseless(), mag.noiseless()
    if args.mag_hard_iron_ut is not None:
        mag = replace(mag, hard_iron_ut=args.mag_hard_iron_ut)
    if args.mag_soft_iron is not None:
        mag = replace(mag, soft_iron=args.mag_soft_iron)
    fault = None
    if args.attitude_fault:
        vals = [float(v) for v in args.attitude_fault.split(",")]
        if not 1 <= len(vals) <= 5:
            raise ValueError("--attitude-fault takes 1 to 5 comma-separated numbers")
        names = ("start_s", "duration_s", "roll_deg", "pitch_deg", "yaw_deg")
        # 1 to 5 numbers given: the fields after them keep their defaults
        fault = AttitudeFault(**dict(zip(names, vals, strict=False)))
    imu_fault = args.imu_fault
    if args.imu2_freeze_at is not None or args.imu2_saturate_at is not None:
        if imu_fault is not None and imu_fault.instance != 1:
            raise ValueError("--imu-fault on another IMU than imu1 cannot be combined with --imu2-freeze/saturate-at")
        imu_fault = replace(imu_fault or ImuFault(instance=1), freeze_at_s=args.imu2_freeze_at,
                            saturate_at_s=args.imu2_saturate_at)
    if imu_fault is not None and imu_fault.instance >= args.imus:
        raise ValueError(f"--imu-fault imu{imu_fault.instance}: only {args.imus} IMU(s) (--imus)")
    anomaly = None
    if args.mag_anomaly_ut is not None or args.mag_anomaly_height_m is not None:
        from firmware_sim.trajectory import make_scenario

        sc = make_scenario(args.scenario, 0)
        anomaly = MagAnomaly(
            args.mag_anomaly_ut if args.mag_anomaly_ut is not None else sc.mag_anomaly_ned_ut,
            args.mag_anomaly_height_m if args.mag_anomaly_height_m is not None else sc.mag_anomaly_height_m,
        )
    sim = SimSettings(
        jit=bool(args.fast or args.jit),
        scenario=args.scenario,
        seed=args.seed,
        loop_rate_hz=args.loop_rate,
        oversample=args.oversample,
        boot_offset_s=args.boot_offset_s,
        imu=imu,
        imu_count=args.imus,
        mag=mag,
        mag_count=args.mags,
        earth_field=EarthField(args.field_ut, args.inclination_deg, args.declination_deg),
        home=Home(args.lat, args.lon, args.alt_m),
        attitude_fault=fault,
        imu_fault=imu_fault,
        imu_mount_deg=args.imu_mount_deg,
        start_in_motion=args.start_in_motion,
        gnss=not args.no_gnss,
        mag_anomaly=anomaly,
        mag_motor_ut_per_a=args.mag_motor_ut_per_a,
        current=CurrentSettings(hover_a=args.hover_current_a),
    ).for_autopilot(args.autopilot)  # PX4's vehicle_imu: the interval mean of the sensor samples, no INS low-pass
    lowpass = {k: v for k, v in (("gyro_lowpass_hz", args.gyro_lowpass_hz), ("accel_lowpass_hz", args.accel_lowpass_hz))
               if v is not None}  # fmt: skip
    if lowpass:  # given on the command line: for either autopilot
        sim = replace(sim, imu=replace(sim.imu, **lowpass))
    preset = args.preset or ("bench" if args.fast else "default")
    link_bps = None
    if args.baud is not None or not (args.out.startswith(("udp", "tcp", "pty")) or args.fast):
        link_bps = (args.baud or 115200) / 10.0
    ep = EndpointSettings(
        autopilot=args.autopilot,
        system_id=args.sysid,
        component_id=args.compid,
        ideal=args.ideal,
        preset=preset,
        default_stream_hz=args.default_stream_hz,
        streams_hz=tuple(args.stream),
        support_message_interval=not args.no_message_interval,
        link_bytes_per_s=link_bps if not args.fast else None,
        block_ticks=2000 if args.fast else 40,
    )
    return sim, ep


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator; returns the exit code (argparse errors raise SystemExit(2))."""
    try:
        return _main(argv)
    except (SystemExit, KeyboardInterrupt):
        raise
    except Exception as exc:  # noqa: BLE001 - last resort: one line for the user, details at -v
        log.debug("unexpected error", exc_info=True)
        print(f"mavahrs-sim: unexpected error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING if args.quiet else (logging.DEBUG if args.verbose > 1 else logging.INFO),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    if args.list_scenarios:
        for n in SCENARIOS:
            print(f"{n:12s} {SCENARIO_DESCRIPTIONS[n]}")
        return EXIT_OK
    if args.fast and not args.tlog:
        parser.error("--fast needs --tlog FILE")
    if args.fast and args.duration <= 0:
        parser.error("--fast needs a positive --duration")
    try:
        sim_settings, ep_settings = settings_from_args(args)
    except ValueError as exc:
        parser.error(str(exc))
    endpoint = Endpoint(Simulation(sim_settings), ep_settings)

    if args.fast:
        stats = write_tlog(endpoint, args.tlog, args.duration, blackouts=args.blackout)
        # the file's size (MAVLink frames plus the tlog's 8-byte time stamps), in MiB as computers count
        size = os.path.getsize(args.tlog)
        print(f"wrote {args.tlog}: {args.duration:g} s simulated, {stats.frames} frames, "
              f"{size / 2**20:.1f} MiB ({size} bytes) in {stats.wall_s:.2f} s", flush=True)
        if args.stats_json:
            write_stats_json(args.stats_json, endpoint, stats, f"tlog {args.tlog}")
        return EXIT_OK

    try:
        link = open_link(args.out, baud=args.baud or 115200)
    except ConfigError as exc:
        parser.error(str(exc))
    except TransportError as exc:
        print(f"mavahrs-sim: {exc}", file=sys.stderr)
        return EXIT_LINK
    stop = {"flag": False}

    def _stop(signum: int, frame: object) -> None:
        stop["flag"] = True

    old = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    desc = describe_link(link)
    if desc.startswith("pty "):
        print(f"PTY {desc.split()[1]}", flush=True)
    print(f"LINK {desc}", flush=True)
    log.info("scenario %s, seed %d, %s, loop %g Hz%s", args.scenario, args.seed, args.autopilot, args.loop_rate,
             " (ideal)" if args.ideal else "")
    tlog = open(args.tlog, "wb") if args.tlog else None
    try:
        stats = run_realtime(
            endpoint, link, args.duration if args.duration > 0 else None,
            should_stop=lambda: stop["flag"], blackouts=args.blackout, tlog=tlog,
            status_every_s=0.0 if args.quiet else 10.0,
        )
    finally:
        link.close()
        if tlog is not None:
            tlog.close()
        for s, h in old.items():
            signal.signal(s, h)
    if args.stats_json:
        write_stats_json(args.stats_json, endpoint, stats, desc)
    log.info("done: %d ticks, %d frames, %d late ticks (max %.1f ms)", stats.ticks, stats.frames,
             stats.late_ticks, stats.max_late_s * 1e3)
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
