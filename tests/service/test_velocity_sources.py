"""GNSS velocity sources through the pipeline: real MAVLink frames of GLOBAL_POSITION_INT, GPS_RAW_INT, GPS2_RAW.

Each test encodes what an autopilot sends, decodes it as the daemon does and
reads the filter's input rows (``sample_hook``): the velocity columns, rotated
into the filter's magnetic NED, the unknown vertical of the receivers' messages,
the fix's age, repeated fixes, the ``auto`` choice and the texts shown.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.errors import ConfigError
from mavahrs.filters.layout import IN_VEL, IN_VEL_AGE
from mavahrs.sensors.geomag import MagneticFieldSettings
from mavahrs.sensors.velocity import VELOCITY_SOURCES, VelocitySelector, fix_age_s
from mavahrs.service.monitor import MonitorSettings, MonitorStatus
from mavahrs.service.pipeline import Pipeline, PipelineSettings

from .test_pipeline import ARRIVAL_US, feed, imu_frames

UNKNOWN = 65535


def make_pipe(**kw):
    s = PipelineSettings(
        filter_name="mahony", out_rate_hz=0.0, magnetic=MagneticFieldSettings(true_north=False, declination_deg=None),
        **kw,
    )  # fmt: skip
    pipe = Pipeline(s, decimal_year=2026.0)
    rows: list[tuple[int, np.ndarray]] = []
    pipe.sample_hook = lambda name, t, row, out: rows.append((t, row.copy()))
    return pipe, rows


def with_messages(frames, extra):
    """Insert (now_us, bytes) messages into an IMU frame list at their arrival time (after equal times)."""
    out = list(frames)
    for item in sorted(extra, key=lambda x: x[0]):
        k = next((i for i, (now, _) in enumerate(out) if now > item[0]), len(out))
        out.insert(k, item)
    return out


def velocity_rows(rows):
    return [(t, r) for t, r in rows if not np.isnan(r[IN_VEL])]


def magnetic(pipe, vn, ve):
    d = pipe.declination.field.declination_rad  # Zürich (WMM): ≈ +3°
    assert 0.02 < d < 0.1
    return math.cos(d) * vn + math.sin(d) * ve, -math.sin(d) * vn + math.cos(d) * ve


def test_global_position_int_velocity_rotated_with_its_age(autopilot, trajectory):
    pipe, rows = make_pipe()
    t_fix = int(trajectory.t_us[200]) - 30_000  # the EKF's velocity 30 ms before it reaches us
    msg = autopilot.global_position_int(t_fix, (1.0, -2.0, 0.5))
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 400), [(int(trajectory.t_us[200]) + ARRIVAL_US, msg)]))
    (t, r), = velocity_rows(rows)
    assert t == trajectory.t_us[201]  # the next sample fed after the message
    np.testing.assert_allclose(r[IN_VEL : IN_VEL + 3], [*magnetic(pipe, 1.0, -2.0), 0.5], atol=1e-12)
    assert r[IN_VEL_AGE] == pytest.approx((t - t_fix // 1000 * 1000) * 1e-6, abs=1e-12)  # time_boot_ms: whole ms
    assert all(np.isnan(row[IN_VEL_AGE]) for _, row in rows if np.isnan(row[IN_VEL]))  # NaN without a velocity


@pytest.mark.parametrize("source,encode", [("gps_raw_int", "gps_raw_int"), ("gps2_raw", "gps2_raw")])
def test_receiver_velocity_from_speed_and_course_vertical_unknown(autopilot, trajectory, source, encode):
    pipe, rows = make_pipe(velocity_source=source)
    t_fix = int(trajectory.t_us[200]) - 150_000  # the receiver's fix, 150 ms before it is sent
    msg = getattr(autopilot, encode)(t_fix, 500, 12000)  # 5 m/s on a course of 120°
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 400), [(int(trajectory.t_us[200]) + ARRIVAL_US, msg)]))
    (t, r), = velocity_rows(rows)
    vn, ve = 5.0 * math.cos(math.radians(120.0)), 5.0 * math.sin(math.radians(120.0))
    np.testing.assert_allclose(r[IN_VEL : IN_VEL + 2], magnetic(pipe, vn, ve), atol=1e-12)
    assert math.isnan(r[IN_VEL + 2])  # no vertical in the message: unknown, not zero
    assert r[IN_VEL_AGE] == pytest.approx((t - t_fix) * 1e-6, abs=1e-12)
    assert pipe.status().velocity_fixes == {source.upper(): 1}


def test_a_repeated_fix_is_fed_once(autopilot, trajectory):
    """ArduPilot sends each GPS_RAW_INT fix twice (same time_usec): the second is not fed again."""
    pipe, rows = make_pipe(velocity_source="gps_raw_int")
    t0 = int(trajectory.t_us[0])
    extra = []
    for k, fix in ((100, 80), (140, 80), (180, 180), (220, 180)):  # two fixes, each sent twice 100 ms apart
        extra.append((int(trajectory.t_us[k]) + ARRIVAL_US, autopilot.gps_raw_int(t0 + fix * 2500, 300 + k, 9000)))
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 400), extra))
    fed = velocity_rows(rows)
    assert [t for t, _ in fed] == [trajectory.t_us[101], trajectory.t_us[181]]
    np.testing.assert_allclose([r[IN_VEL + 1] for _, r in fed], [magnetic(pipe, 0.0, 4.0)[1], magnetic(pipe, 0.0, 4.8)[1]])
    st = pipe.status()
    assert st.velocity_fixes == {"GPS_RAW_INT": 2} and st.velocity_skipped == {"repeated": 2}


def test_unusable_receiver_messages_are_skipped(autopilot, trajectory):
    pipe, rows = make_pipe(velocity_source="gps_raw_int")
    t0 = int(trajectory.t_us[0])
    extra = [
        (int(trajectory.t_us[50]) + ARRIVAL_US, autopilot.gps_raw_int(t0 + 1000, 300, 9000, fix_type=2)),  # 2D
        (int(trajectory.t_us[100]) + ARRIVAL_US, autopilot.gps_raw_int(t0 + 2000, UNKNOWN, 9000)),  # speed unknown
        (int(trajectory.t_us[150]) + ARRIVAL_US, autopilot.gps_raw_int(t0 + 3000, 250, UNKNOWN)),  # moving, no course
        (int(trajectory.t_us[200]) + ARRIVAL_US, autopilot.gps_raw_int(t0 + 4000, 0, UNKNOWN)),  # still: zero
        (int(trajectory.t_us[250]) + ARRIVAL_US, autopilot.gps_raw_int(1_796_196_594_000_000, 100, 0)),  # UNIX time
    ]
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 400), extra))
    fed = velocity_rows(rows)
    assert [t for t, _ in fed] == [trajectory.t_us[201], trajectory.t_us[251]]
    np.testing.assert_allclose(fed[0][1][IN_VEL : IN_VEL + 2], [0.0, 0.0], atol=0)
    assert fed[0][1][IN_VEL_AGE] == pytest.approx((trajectory.t_us[201] - t0 - 4000) * 1e-6)
    assert fed[1][1][IN_VEL_AGE] == 0.0  # a UNIX time stamp is on another clock: as old as the sample
    assert pipe.status().velocity_skipped == {"no_fix": 1, "unknown_velocity": 2}


def test_auto_switches_to_gps_raw_when_global_position_int_goes_silent_and_back(autopilot, trajectory):
    """GLOBAL_POSITION_INT at 10 Hz stops from 5 s to 10 s; GPS_RAW_INT (5 Hz fixes, each sent twice) all along."""
    pipe, rows = make_pipe()
    t0 = int(trajectory.t_us[0])
    extra = []
    for k in range(0, 5200, 40):  # every 100 ms
        now = int(trajectory.t_us[k]) + ARRIVAL_US
        s = (k / 400.0)
        if not 5.0 <= s < 10.0:
            extra.append((now, autopilot.global_position_int(int(trajectory.t_us[k]), (1.0, 0.0, -0.5))))
        fix_t = t0 + (k // 80) * 200_000 - 150_000  # a 5 Hz receiver fix, 150 ms before it is sent
        extra.append((now + 100, autopilot.gps_raw_int(fix_t, 200, 0)))
    frames = with_messages(imu_frames(autopilot, trajectory, 0, 5200), extra)
    lines = {}
    for when in (4.5, 9.5, 12.5):
        cut = next(i for i, (now, _) in enumerate(frames) if now > t0 + when * 1e6)
        feed(pipe, frames[:cut])
        frames = frames[cut:]
        lines[when] = pipe.status(int(t0 + when * 1e6))
    feed(pipe, frames)
    lines[16.0] = pipe.status(int(t0 + 16.0 * 1e6))  # every source silent for more than 2 s

    def source_at(t_s):  # which message fed the row (GPS_RAW_INT has no vertical)
        return ["GPS_RAW_INT" if math.isnan(r[IN_VEL + 2]) else "GPI" for t, r in velocity_rows(rows)
                if t_s[0] <= (t - t0) * 1e-6 < t_s[1]]  # fmt: skip

    assert set(source_at((0.0, 5.0))) == {"GPI"} and len(source_at((0.0, 5.0))) == 50
    # GPS_RAW_INT waits until GLOBAL_POSITION_INT (last at 4.9 s) has been silent for 2 s
    assert source_at((5.0, 6.9)) == []
    gps = source_at((6.9, 10.0))
    assert set(gps) == {"GPS_RAW_INT"} and len(gps) == 16  # 5 Hz fixes from 6.9 s on: the repeats are not fed
    assert set(source_at((10.0, 13.0))) == {"GPI"}  # back at once: never both in one interval
    assert [lines[w].velocity for w in (4.5, 9.5, 12.5, 16.0)] == [
        "vel GPI 10 Hz", "vel GPS_RAW 5 Hz", "vel GPI 10 Hz", "vel none"
    ]
    assert "| vel GPS_RAW 5 Hz |" in lines[9.5].line()
    assert pipe.velocity_selector.switches == 2


def test_none_feeds_no_velocity_and_requests_none(autopilot, trajectory):
    pipe, rows = make_pipe(velocity_source="none")
    t0 = int(trajectory.t_us[0])
    extra = [(int(trajectory.t_us[k]) + ARRIVAL_US, autopilot.global_position_int(t0 + k * 2500, (1.0, 2.0, 0.0)))
             for k in range(0, 800, 40)]  # fmt: skip
    extra += [(int(trajectory.t_us[k]) + ARRIVAL_US + 1, autopilot.gps_raw_int(t0 + k * 2500, 100, 0)) for k in range(0, 800, 80)]
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 800), extra))
    assert velocity_rows(rows) == [] and len(rows) == 800
    st = pipe.status(t0 + 2_000_000)
    assert st.velocity == "vel none" and st.velocity_fixes == {}
    assert not {"GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW"} & {s.message for s in st.streams}
    assert pipe.declination.known  # the positions still feed the magnetic model


@pytest.mark.parametrize(
    "source,wanted",
    [("auto", {"GLOBAL_POSITION_INT", "GPS_RAW_INT"}), ("gps2_raw", {"GPS2_RAW"}), ("gps_raw_int", {"GPS_RAW_INT"})],
)
def test_stream_requests_ask_for_the_source_messages(autopilot, trajectory, source, wanted):
    pipe, _ = make_pipe(velocity_source=source)
    feed(pipe, imu_frames(autopilot, trajectory, 0, 10))
    names = {s.message for s in pipe.status().streams}
    assert names & {"GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW"} == wanted


def test_receiver_only_monitor_uses_the_receivers_velocity(autopilot, trajectory):
    pipe, rows = make_pipe(monitor=MonitorSettings(receiver_velocity_only=True))
    t0 = int(trajectory.t_us[0])
    extra = [(int(trajectory.t_us[k]) + ARRIVAL_US, autopilot.global_position_int(t0 + k * 2500, (1.0, 2.0, 0.0)))
             for k in range(0, 800, 40)]  # fmt: skip
    extra += [(int(trajectory.t_us[k]) + ARRIVAL_US + 1, autopilot.gps_raw_int(t0 + k * 2500, 100, 0)) for k in range(0, 800, 80)]
    feed(pipe, with_messages(imu_frames(autopilot, trajectory, 0, 800), extra))
    fed = velocity_rows(rows)
    assert len(fed) == 10 and all(math.isnan(r[IN_VEL + 2]) for _, r in fed)  # GPS_RAW_INT only
    assert {s.message for s in pipe.status().streams} >= {"GPS_RAW_INT", "GPS2_RAW"}
    assert "GLOBAL_POSITION_INT" not in {s.message for s in pipe.status().streams}
    with pytest.raises(ConfigError) as exc:
        PipelineSettings(velocity_source="global_position_int", monitor=MonitorSettings(receiver_velocity_only=True))
    assert str(exc.value) == (
        "velocity_source = global_position_int contradicts monitor.receiver_velocity_only "
        "(the receiver's GPS_RAW_INT / GPS2_RAW only): choose auto, gps_raw_int, gps2_raw or none"
    )


def test_monitor_text_names_the_velocity_source():
    st = MonitorStatus(tilt_deg=0.84, heading_deg=1.23, warning=False, comparisons=3, unmatched=0, episodes=0,
                       velocity_source="GPS_RAW")  # fmt: skip
    assert st.text() == "AP cmp: tilt 0.8° hdg +1.2° (vel GPS_RAW)"
    warn = MonitorStatus(12.0, -3.0, True, 9, 0, 1, "GPI")
    assert warn.text() == "AP cmp: tilt 12.0° hdg -3.0° WARN (vel GPI)"


def test_deprecated_use_gnss_velocity_false_means_none():
    pipe = Pipeline(PipelineSettings(filter_name="mahony", use_gnss_velocity=False))
    assert pipe.settings.effective_velocity_source == "none" and pipe.velocity_selector.messages == ()
    assert pipe.drain_notices() == [
        (30, 'pipeline.use_gnss_velocity = false is deprecated: set velocity_source = "none"')
    ]
    with pytest.raises(ConfigError, match="velocity_source must be one of auto, global_position_int"):
        PipelineSettings(velocity_source="gps")


def test_cli_choices_are_the_settings_values():
    from mavahrs.cli.common import VELOCITY_SOURCE_CHOICES

    assert VELOCITY_SOURCE_CHOICES == VELOCITY_SOURCES


class _Msg:
    def __init__(self, kind, **fields):
        self._kind = kind
        self.__dict__.update(fields)

    def get_type(self):
        return self._kind


def test_selector_reordered_and_a_new_clock():
    """A fix older than the last used (by < 2 s) is a reordered message; by more, a new time base (reboot)."""
    sel = VelocitySelector("gps_raw_int")

    def gps(t):
        return _Msg("GPS_RAW_INT", time_usec=t, fix_type=3, vel=100, cog=0)

    assert sel.offer(gps(5_000_000), 0, None) is not None
    assert sel.offer(gps(4_800_000), 100_000, None) is None
    assert sel.offer(gps(1_000_000), 200_000, None) is not None
    assert sel.counters == {"reordered": 1}
    assert fix_age_s(1_250_000, 1_000_000) == 0.25 and fix_age_s(1_250_000, None) == 0.0


def test_replay_velocity_line_after_a_switch():
    from types import SimpleNamespace

    from mavahrs.replay import format_velocity

    inp = SimpleNamespace(velocity_source="auto", velocity_fixes={"GLOBAL_POSITION_INT": 1200, "GPS_RAW_INT": 40, "GPS2_RAW": 0})
    assert format_velocity(inp) == (
        "velocity: GLOBAL_POSITION_INT, 1200 fixes + GPS_RAW_INT, 40 fixes (velocity_source auto)"
    )
    inp = SimpleNamespace(velocity_source="auto, receiver only", velocity_fixes={"GPS_RAW_INT": 0, "GPS2_RAW": 0})
    assert format_velocity(inp) == "velocity: none (velocity_source auto, receiver only: no usable fix in the log)"


def test_px4_auto_prefers_the_receiver_over_ekf2s_velocity(trajectory, make_autopilot):
    """On PX4, GLOBAL_POSITION_INT is EKF2's velocity: ``auto`` takes GPS_RAW_INT while it arrives, both are requested."""
    ap = make_autopilot(1, 1, autopilot=12)  # PX4: HIGHRES_IMU
    pipe, rows = make_pipe()
    t0 = int(trajectory.t_us[0])
    frames = [(0, ap.heartbeat())]
    for k in range(800):
        t = int(trajectory.t_us[k])
        frames.append((t + ARRIVAL_US, ap.highres_imu(t, [0.0, 0.0, -9.80665], [0.0, 0.0, 0.0], [0.2, 0.0, 0.45])))
    extra = [(int(trajectory.t_us[k]) + ARRIVAL_US, ap.global_position_int(t0 + k * 2500, (1.0, 2.0, 0.0)))
             for k in range(0, 800, 40)]  # fmt: skip
    extra += [(int(trajectory.t_us[k]) + ARRIVAL_US + 1, ap.gps_raw_int(t0 + k * 2500, 100, 0)) for k in range(0, 800, 80)]
    feed(pipe, with_messages(frames, extra))
    fed = velocity_rows(rows)
    assert len(fed) == 10 and all(math.isnan(r[IN_VEL + 2]) for _, r in fed)  # GPS_RAW_INT only
    assert {s.message for s in pipe.status().streams} >= {"GPS_RAW_INT", "GLOBAL_POSITION_INT"}


def test_selector_px4_order_falls_back_to_global_position_int():
    """PX4's order: the receiver first; EKF2's GLOBAL_POSITION_INT only once the receiver is silent for 2 s."""
    from mavahrs.sensors.profiles import get_profile
    from mavahrs.sensors.velocity import AUTO_ORDER, PX4_AUTO_ORDER

    assert get_profile("px4").velocity_order == PX4_AUTO_ORDER
    assert get_profile("ardupilot").velocity_order == AUTO_ORDER == get_profile("generic").velocity_order
    sel = VelocitySelector("auto")
    sel.set_auto_order(PX4_AUTO_ORDER)
    assert sel.messages == PX4_AUTO_ORDER

    def gps(t):
        return _Msg("GPS_RAW_INT", time_usec=t, fix_type=3, vel=100, cog=0)

    def gpi(t_ms):
        return _Msg("GLOBAL_POSITION_INT", time_boot_ms=t_ms, lat=1, lon=1, vx=100, vy=0, vz=0)

    assert sel.offer(gps(1_000_000), 1_000_000, None) is not None
    assert sel.offer(gpi(1_050), 1_050_000, None) is None  # standby while the receiver arrives
    assert sel.offer(gpi(3_100), 3_100_000, None) is not None  # receiver silent > 2 s
    assert sel.current == "GLOBAL_POSITION_INT" and sel.counters == {"standby": 1}
    receiver_only = VelocitySelector("auto", receiver_only=True)
    receiver_only.set_auto_order(PX4_AUTO_ORDER)  # no effect: the receivers only
    assert receiver_only.messages == ("GPS_RAW_INT", "GPS2_RAW")
