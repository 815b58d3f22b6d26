#!/usr/bin/env python3
"""What an ArduPilot SITL DataFlash log's data lag behind the simulator's truth, and ``best`` against EKF3.

    python3 scripts/bench_onboard.py                          # the shared ../shared/data/sitl/arducopter_onboard.BIN
    python3 scripts/bench_onboard.py a.BIN b.BIN --variants   # several logs; best with other delays and GPS ages

For each log (it must hold ``SIM``, the simulator's true attitude, and ``SIM2``, its true velocity):

* every autopilot attitude the log holds (EKF3 per core, ATT, DCM) against ``SIM``: inclination RMS,
  degrees, from 10 s after the first IMU sample fed;
* the lag of each IMU instance's ``GyrX/Y/Z`` behind the truth: the shift τ for which the gyro's mean
  over each interval between two ``SIM`` records, taken τ later, is closest (RMS) to the rate the two
  ``SIM`` quaternions imply (searched from −20 to 40 ms in 0.5 ms steps), beside the reader's model,
  the low-pass group delay √2 / (2π · ``INS_GYRO_FILTER``);
* the lag of the ``GPS`` velocity (``Spd``, ``GCrs``) behind ``SIM2``'s true NE velocity: the shift
  (0–400 ms, 5 ms steps) at which they agree best, beside what the reader takes (``GPS1_DELAY_MS``,
  else the simulator's ``SIM_GPS1_LAG_MS``);
* ``best`` as ``mavahrs replay`` runs it (the reader's rows, delay and GNSS ages) against ``SIM``;
  with ``--variants`` also with other ``sensor_delay_s`` and GNSS fix ages, and with EKF3's own
  velocity (``XKF1`` core 0, what GLOBAL_POSITION_INT carries in a tlog) instead of the receiver's.

Inclination only: it does not depend on the declination, which the replay applies to outputs (the
raw filter outputs here are in the magnetic frame).  Results in ``docs/accuracy.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.evaluation.tlogdata import interpolate_attitude  # noqa: E402
from mavahrs.filters import create  # noqa: E402
from mavahrs.filters.layout import FLAG_NOT_INITIALISED, IN_VEL, IN_VEL_AGE, OUT_FLAGS, OUT_Q  # noqa: E402
from mavahrs.logs.dataflash import _gps_lag_us, decode, read_dataflash, scan  # noqa: E402

SHARED_BIN = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "sitl" / "arducopter_onboard.BIN"
SKIP_US = 10_000_000


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], 1)  # fmt: skip


def _inclination(t_us: np.ndarray, q: np.ndarray, truth: tuple[np.ndarray, np.ndarray], start_us: int) -> float:
    tr, qr = truth
    qe = interpolate_attitude(t_us.astype(float), q, tr.astype(float))
    ok = np.all(np.isfinite(qe), 1) & (tr >= start_us + SKIP_US)
    return summarize(qe[ok], qr[ok]).inclination_rms_deg


def gyro_lag_ms(t_s: np.ndarray, gyro: np.ndarray, truth: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """(lag τ ms, RMS rate difference °/s at τ) of a gyro behind the truth's attitude."""
    tr, qr = truth
    rel = _qmul(qr[:-1] * np.array([1.0, -1.0, -1.0, -1.0]), qr[1:])
    rel *= np.sign(rel[:, :1])
    dt = np.diff(tr) * 1e-6
    w = 2.0 * rel[:, 1:] / np.where(dt > 0, dt, np.nan)[:, None]  # mean body rate over each interval
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum((gyro[1:] + gyro[:-1]) / 2 * np.diff(t_s)[:, None], 0)])
    best = (np.inf, 0.0)
    for tau in np.arange(-20.0, 40.01, 0.5):
        a = tr[:-1] * 1e-6 + tau * 1e-3
        b = tr[1:] * 1e-6 + tau * 1e-3
        inside = (dt > 0.02) & (dt < 0.06) & (a > t_s[0]) & (b < t_s[-1])
        ia = np.stack([np.interp(a, t_s, integral[:, k]) for k in range(3)], 1)
        ib = np.stack([np.interp(b, t_s, integral[:, k]) for k in range(3)], 1)
        e = float(np.sqrt(np.mean(np.sum(((ib - ia) / dt[:, None] - w)[inside] ** 2, 1))))
        best = min(best, (e, float(tau)))
    return best[1], float(np.degrees(best[0]))


def gps_lag_ms(gps: dict[str, np.ndarray], sim2: dict[str, np.ndarray]) -> tuple[float, float]:
    """(lag ms, RMS m/s at it) of the GPS record's horizontal velocity behind SIM2's true velocity."""
    ok = gps["Status"] >= 3
    tg = gps["TimeUS"][ok] * 1e-6
    crs = np.radians(gps["GCrs"][ok])
    vn, ve = gps["Spd"][ok] * np.cos(crs), gps["Spd"][ok] * np.sin(crs)
    ts = sim2["TimeUS"] * 1e-6
    best = (np.inf, 0.0)
    for lag in np.arange(0.0, 400.1, 5.0):
        e = np.sqrt(np.mean((np.interp(tg - lag * 1e-3, ts, sim2["VN"]) - vn) ** 2
                            + (np.interp(tg - lag * 1e-3, ts, sim2["VE"]) - ve) ** 2))  # fmt: skip
        best = min(best, (float(e), float(lag)))
    return best[1], best[0]


def _best(prep: object, truth: tuple[np.ndarray, np.ndarray], delay: float | None = None, age_add_s: float = 0.0,
          rows: np.ndarray | None = None) -> float:  # fmt: skip
    """``best``'s inclination RMS against the truth over the reader's rows (or ``rows``), with changes."""
    saved_rows, saved_delay = prep.rows, prep.sensor_delay_s  # type: ignore[attr-defined]
    try:
        if rows is not None:
            prep.rows = rows  # type: ignore[attr-defined]
        if age_add_s:
            prep.rows = prep.rows.copy()  # type: ignore[attr-defined]
            prep.rows[:, IN_VEL_AGE] += age_add_s  # type: ignore[attr-defined]
        if delay is not None:
            prep.sensor_delay_s = delay  # type: ignore[attr-defined]
        out = prep.run_filter(create("best"))  # type: ignore[attr-defined]
    finally:
        prep.rows, prep.sensor_delay_s = saved_rows, saved_delay  # type: ignore[attr-defined]
    init = (out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
    t = prep.t_us  # type: ignore[attr-defined]
    return _inclination(t[init], out[init, OUT_Q : OUT_Q + 4], truth, int(t[0]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="*", type=Path, default=[SHARED_BIN], help="ArduPilot SITL .BIN logs")
    ap.add_argument("--variants", action="store_true", help="best with other delays, GNSS ages, EKF3's velocity")
    args = ap.parse_args(argv)
    for path in args.logs:
        if not path.exists():
            print(f"{path}: not found", file=sys.stderr)
            return 2
        li = read_dataflash(path)
        prep = li.inputs
        if "SIM truth" not in li.references:
            print(f"{path.name}: no SIM truth: skipped")
            continue
        truth = li.references["SIM truth"]
        start = int(prep.t_us[0])
        print(f"== {path.name}: {prep.n} IMU samples fed at {prep.rate_hz():.0f} Hz (instance {prep.instance})")
        for name, (t_ref, q_ref) in li.references.items():
            if name != "SIM truth":
                print(f"  {name:<24} inclination {_inclination(t_ref, q_ref, truth, start):.3f}°")
        sc = scan(np.fromfile(path, np.uint8))
        imu = decode(sc, "IMU")
        assert imu is not None
        inst = imu["I"] if "I" in imu else np.zeros(imu["TimeUS"].shape[0], np.uint8)
        for i in np.unique(inst).tolist():
            m = inst == i
            g = np.stack([imu["GyrX"][m], imu["GyrY"][m], imu["GyrZ"][m]], 1).astype(float)
            lag, e = gyro_lag_ms(imu["TimeUS"][m] * 1e-6, g, truth)
            print(f"  IMU {i} gyro behind the truth: {lag:.1f} ms (RMS {e:.3f} °/s there); the reader's delay "
                  f"{prep.sensor_delay_s * 1e3:.2f} ms")  # fmt: skip
        gps, sim2 = decode(sc, "GPS"), decode(sc, "SIM2")
        if gps is not None and sim2 is not None and "VN" in sim2:
            lag, e = gps_lag_ms(gps, sim2)
            taken_us, why = _gps_lag_us(li.parameters)
            print(f"  GPS velocity behind SIM2: {lag:.0f} ms (RMS {e:.3f} m/s there); the reader takes "
                  f"{taken_us / 1000:g} ms ({why})")  # fmt: skip

        print(f"  best (as replay runs it)   inclination {_best(prep, truth):.3f}°")
        if not args.variants:
            continue
        for d in (0.0, 0.0025, 0.005, 0.0075, 0.015, 0.02):
            print(f"  best, sensor_delay_s {d * 1e3:4.1f} ms  {_best(prep, truth, delay=d):.3f}°")
        for add in (-0.1, 0.01, 0.02, 0.03, 0.1):
            print(f"  best, GNSS fix age {add * 1e3:+4.0f} ms  {_best(prep, truth, age_add_s=add):.3f}°")
        x = decode(sc, "XKF1")
        if x is not None and "VN" in x:
            c0 = x["C"] == 0 if "C" in x else np.ones(x["TimeUS"].shape[0], bool)
            tx = x["TimeUS"][c0].astype(np.int64)
            rows = prep.rows.copy()
            rows[:, IN_VEL : IN_VEL + 3] = np.nan
            rows[:, IN_VEL_AGE] = np.nan
            j = np.searchsorted(prep.t_us, tx, side="left")
            ok = j < prep.n
            d = prep.declination_rad[j[ok]]  # true north → the filters' magnetic frame, as the reader rotates GPS
            vn, ve = x["VN"][c0][ok], x["VE"][c0][ok]
            rows[j[ok], IN_VEL] = np.cos(d) * vn + np.sin(d) * ve
            rows[j[ok], IN_VEL + 1] = -np.sin(d) * vn + np.cos(d) * ve
            rows[j[ok], IN_VEL + 2] = x["VD"][c0][ok]
            rows[j[ok], IN_VEL_AGE] = (prep.t_us[j[ok]] - tx[ok]) * 1e-6
            print(f"  best with EKF3's velocity (XKF1 core 0) instead of GPS  {_best(prep, truth, rows=rows):.3f}°")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
