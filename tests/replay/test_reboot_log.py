"""A tlog in which the autopilot rebooted (its boot clock starts again), as ``mavahrs run --log`` records a session
whose flight controller restarted or whose port came back with a restarted one: ``mavahrs replay`` compares and
judges it boot by boot.  Until user7 the references were sorted by time over both boots, the second opinion judged
both boots at once, and the header's span ran from the first sample to the last: on such a log the comparison
table was empty or 50° RMS, a false ``IMU2 gyro off by 26.8 dps`` came out, and the rate read 0 or 730 Hz."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def two_boots(tmp_path_factory: pytest.TempPathFactory,
              sim_tlog_writer: Callable[..., Path]) -> tuple[Path, Path, Path]:  # fmt: skip
    """firmware_sim: boot A (30 s after power-up, no fault), then after 2 s boot B (from 0 s, a 3° tilt error put
    into the autopilot's own attitude at 15–21 s), written one after the other into one tlog."""
    from mavahrs.protocol.tlog import iter_tlog, tlog_record

    d = tmp_path_factory.mktemp("reboot")
    a = sim_tlog_writer(d / "a.tlog", "--scenario", "aggressive", "--duration", "25", "--seed", "11",
                       "--boot-offset-s", "30")  # fmt: skip
    b = sim_tlog_writer(d / "b.tlog", "--scenario", "aggressive", "--duration", "25", "--seed", "12",
                       "--attitude-fault", "15,6,3")  # fmt: skip
    ra, rb = list(iter_tlog(a)), list(iter_tlog(b))
    shift = ra[-1][0] + 2_000_000 - rb[0][0]
    ab = d / "ab.tlog"
    with ab.open("wb") as f:
        f.writelines(tlog_record(t, frame) for t, frame in ra)
        f.writelines(tlog_record(t + shift, frame) for t, frame in rb)
    return a, b, ab


def _in_flight(result: object) -> list[tuple[float, str]]:
    from mavahrs.replay.engine import _monitor_of

    got = _monitor_of(result)  # type: ignore[arg-type]
    assert got is not None
    return [(e.t_ms, e.text) for e in got[0].events if e.in_flight]


def test_a_log_with_a_reboot_is_compared_and_judged_boot_by_boot(two_boots: tuple[Path, Path, Path]) -> None:
    from mavahrs import replay as rp
    from mavahrs.replay.engine import compare

    a, b, ab = (rp.replay(str(p), rp.ReplaySettings()) for p in two_boots)
    assert ab.engine == "pipeline" and any("rebooted" in n for n in ab.notes)
    # the header: each boot's span, at the stream's rate
    assert ab.inputs.duration_s() == pytest.approx(a.inputs.duration_s() + b.inputs.duration_s(), abs=0.05)
    assert ab.inputs.rate_hz() == pytest.approx(b.inputs.rate_hz(), rel=0.01)
    # against the simulator's truth: each boot as replayed alone, sample-weighted
    rows = {r.reference: r for r in compare(ab, skip_s=5.0)}
    single = [{r.reference: r for r in compare(x, skip_s=5.0)} for x in (a, b)]
    for ref in ("SIMSTATE truth", "autopilot ATTITUDE"):
        n = [s[ref].samples for s in single]
        assert rows[ref].samples == pytest.approx(sum(n), abs=4)
        want = math.sqrt(sum(s[ref].inclination_rms_deg ** 2 * k for s, k in zip(single, n, strict=True)) / sum(n))
        assert rows[ref].inclination_rms_deg == pytest.approx(want, abs=0.05), ref
    # the second opinion: boot B's tilt error, when replaying B alone says it; nothing else in flight
    said, alone = _in_flight(ab), _in_flight(b)
    assert _in_flight(a) == [] and alone and 15_000.0 <= alone[0][0] <= 17_000.0
    assert len(said) == 1 and "AP off" in said[0][1] and abs(said[0][0] - alone[0][0]) <= 100.0, said
    # its series: boot A's, one NaN row (charts break their lines there), boot B's
    import numpy as np

    from mavahrs.replay.engine import _monitor_of

    series = _monitor_of(ab)[0]  # type: ignore[index]
    gap = np.flatnonzero(np.isnan(series.t_ms))
    assert gap.size == 1 and np.isnan(series.tilt_threshold_deg[gap[0]])
    assert series.t_ms[gap[0] - 1] > series.t_ms[gap[0] + 1]


def test_the_plot_of_a_log_with_a_reboot_draws_each_boot_against_its_own_reference(
    two_boots: tuple[Path, Path, Path], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Each boot on its own clock, lines broken between boots (a NaN row), each boot's truth beside its estimate
    as the plot of that boot alone draws it."""
    import numpy as np

    from mavahrs import replay as rp
    from mavahrs.evaluation import plots

    drawn: list[tuple[np.ndarray, dict]] = []

    def capture(path, t_s, est, **kw):  # type: ignore[no-untyped-def]
        drawn.append((np.asarray(t_s), {"est": est, **kw}))
        return Path(path)

    monkeypatch.setattr(plots, "plot_attitude", capture)
    a, b, ab = (rp.replay(str(p), rp.ReplaySettings()) for p in two_boots)
    for r, name in ((a, "a"), (b, "b"), (ab, "ab")):
        rp.plot_replay(r, tmp_path / f"{name}.png")
    (t_a, _), (t_b, kw_b), (t_ab, kw_ab) = drawn
    gap = np.flatnonzero(np.isnan(t_ab))
    assert gap.size == 1 and gap[0] == t_a.size, "one break, between the two boots"
    n = t_ab.size - gap[0] - 1  # boot B's samples (the reboot's first one is dropped, as the daemon drops it)
    assert t_b.size - 1 <= n <= t_b.size and np.array_equal(t_ab[gap[0] + 1 :], t_b[-n:])
    assert kw_ab["reference_label"] == kw_b["reference_label"]
    ref_b, ref_ab = kw_b["reference_q"][-n:], kw_ab["reference_q"][gap[0] + 1 :]
    both = np.isfinite(ref_b).all(axis=1) & np.isfinite(ref_ab).all(axis=1)  # but the boot's edge
    assert both.sum() >= n - 2 and np.allclose(ref_ab[both], ref_b[both], atol=1e-9)
    t_ap, _q_ap = kw_ab["others"]["autopilot ATTITUDE"]
    assert np.isnan(t_ap).sum() == 1


def test_the_audit_and_the_output_tlog_of_a_log_with_a_reboot_cover_both_boots(
    two_boots: tuple[Path, Path, Path],
) -> None:
    """The audit's row: both boots' duration, compared span and WARNINGs (it gave boot A's alone: 14.98 s compared,
    no alarm); the frames the daemon's pipeline sent at 50 Hz pair one-to-one with the samples counted as sent
    (after a reboot none counted, so `--output` placed 2500 frames by 1250 samples)."""
    from mavahrs import replay as rp
    from mavahrs.fleet.audit import AuditSettings, summarise_log

    rows = [summarise_log(p) for p in two_boots]
    a, b, ab = rows
    assert ab.error == "" and ab.engine == "pipeline"
    assert ab.duration_s == pytest.approx(a.duration_s + b.duration_s, abs=0.05)
    assert ab.compared_s == pytest.approx(a.compared_s + b.compared_s, abs=0.2)
    assert a.alarms == 0 and b.alarms == 1 and ab.alarms == 1
    assert abs(float(ab.alarm_times_s) - float(b.alarm_times_s)) <= 0.1
    res = rp.replay(str(two_boots[2]), AuditSettings().replay)
    track = res.tracks["best"]
    assert track.frames is not None and int(track.sent.sum()) == len(track.frames) > 2000


def test_the_replay_csv_of_a_log_with_a_reboot_is_drawn_on_each_boots_clock(
    two_boots: tuple[Path, Path, Path], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``mavahrs plot OUT.csv``: the CSV's time_s (boot time) with one break where the autopilot rebooted (it drew
    seconds from the first row, boot B at negative times, and a line from A's last row to B's first)."""
    import numpy as np

    from mavahrs.cli import main
    from mavahrs.evaluation import plots

    csv = tmp_path / "ab.csv"
    assert main(["replay", str(two_boots[2]), "--csv", str(csv)]) == 0
    drawn: list[tuple[np.ndarray, str]] = []

    def capture(path, t_s, est, **kw):  # type: ignore[no-untyped-def]
        drawn.append((np.asarray(t_s), kw.get("time_label", "")))
        return Path(path)

    monkeypatch.setattr(plots, "plot_attitude", capture)
    assert main(["plot", str(csv), "-o", str(tmp_path / "ab.png")]) == 0
    t, label = drawn[-1]
    time_s = np.loadtxt(csv, delimiter=",", skiprows=1, usecols=0)
    gap = np.flatnonzero(np.isnan(t))
    assert gap.size == 1 and np.array_equal(np.delete(t, gap), time_s) and time_s[gap[0]] < time_s[gap[0] - 1]
    assert label == "autopilot boot time (each boot's own clock), s"


def test_evaluate_scores_a_log_with_a_reboot_boot_by_boot(two_boots: tuple[Path, Path, Path],
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``mavahrs evaluate`` against the simulator's truth: each boot's samples against that boot's truth, the
    filter started again at the reboot and told what the pipeline tells it (sensor delay, an autopilot's stream,
    a multirotor), ``--skip`` from each boot's start: the sample-weighted result of the two boots evaluated alone
    (until user7: 0.99° from truth sorted over both boots; with the boots apart but the filter running on and
    not configured, 93.6°)."""
    import json

    from mavahrs.cli import main

    got = []
    for p in two_boots:
        assert main(["evaluate", str(p), "-f", "best", "--skip", "5", "--json"]) == 0
        got.append(json.loads(capsys.readouterr().out)["filters"]["best"])
    a, b, ab = got
    assert ab["samples"] == pytest.approx(a["samples"] + b["samples"], abs=4)
    for key in ("inclination_rms_deg", "heading_rms_deg"):
        want = math.sqrt((a[key] ** 2 * a["samples"] + b[key] ** 2 * b["samples"]) / (a["samples"] + b["samples"]))
        assert ab[key] == pytest.approx(want, abs=0.05), key
