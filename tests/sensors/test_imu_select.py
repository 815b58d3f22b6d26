"""IMU instance selection: absent (all-zero) instances, fixed choice, auto fail-over within 1 s."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.errors import ConfigError
from mavahrs.sensors.imu_select import ImuSelector, ImuSelectSettings
from mavahrs.sensors.sample import GYRO

NAMES = {0: "RAW_IMU", 1: "SCALED_IMU2", 2: "SCALED_IMU3"}
DT_US = 2500  # 400 Hz


def sample(imu, t_us, gyro, accel, sat=0):
    return (imu, t_us, *gyro, *accel, math.nan, math.nan, math.nan, None, sat, 0)


class Bench:
    """Feeds several instances in lock-step with independent noise (what a real autopilot sends)."""

    def __init__(self, settings=None, n=2, seed=1):
        self.sel = ImuSelector(settings or ImuSelectSettings())
        self.rng = np.random.default_rng(seed)
        self.n = n
        self.fed: list[tuple[int, int]] = []

    def step(self, t_us, override=None, skip=()):
        for imu in range(self.n):
            if imu in skip:
                continue
            g = tuple(self.rng.normal(0.0, 0.002, 3))
            a = tuple(np.array([0.0, 0.0, -9.8]) + self.rng.normal(0.0, 0.02, 3))
            v = sample(imu, t_us, g, a)
            if override and imu in override:
                v = override[imu](v)
            if self.sel.observe(NAMES[imu], v):
                self.fed.append((imu, t_us))

    def run(self, t0_s, t1_s, **kw):
        for k in range(int(t0_s * 400), int(t1_s * 400)):
            self.step(k * DT_US, **kw)

    def first_fed_from(self, imu):
        return next(t for i, t in self.fed if i == imu)


def test_all_zero_instance_is_never_fed_even_when_forced():
    for imu_setting in ("auto", "1"):
        b = Bench(ImuSelectSettings(imu=imu_setting))
        zero = {1: lambda v: (1, v[1], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *v[8:])}
        b.run(0, 2, override=zero)
        assert all(i == 0 for i, _ in b.fed)
        states = {s.imu_id: s.state for s in b.sel.instances()}
        assert states[1] == "absent (all-zero)"
        if imu_setting == "auto":
            assert b.sel.selected == 0 and len(b.fed) == 800
        else:
            assert b.fed == []  # --imu 1 with no IMU 1: nothing to filter


def test_auto_prefers_instance_0_and_feeds_only_it():
    b = Bench()
    b.run(0, 1)
    assert b.sel.selected == 0
    assert {i for i, _ in b.fed} == {0} and len(b.fed) == 400
    assert [s.state for s in b.sel.instances()] == ["ok", "ok"]


def test_fixed_instance():
    b = Bench(ImuSelectSettings(imu="1"))
    b.run(0, 1)
    assert {i for i, _ in b.fed} == {1}
    assert "fixed" in b.sel.reason


def test_fail_over_when_selected_goes_stale_within_1_s():
    b = Bench()
    b.run(0, 2)
    b.run(2, 4, skip=(0,))  # instance 0 stops at t = 2 s
    t_switch = b.first_fed_from(1)
    assert 2.0e6 < t_switch <= 3.0e6
    assert b.sel.selected == 1 and "stale" in b.sel.reason
    ch = b.sel.pop_changes()
    assert (ch[-1].old, ch[-1].new) == (0, 1)


def test_link_outage_is_not_a_stale_instance():
    """All instances silent for 2 s (a link outage); the slower secondary happens to speak first."""
    b = Bench()
    b.run(0, 2)
    b.step(int(4.0e6), skip=(0,))  # instance 1 resumes first …
    b.step(int(4.0e6) + DT_US)  # … instance 0 a moment later
    b.run(4.01, 5)
    assert b.sel.selected == 0 and b.sel.pop_changes()[-1].new == 0
    assert {i for i, t in b.fed if t > 4.0e6} == {0}


def test_fail_over_when_selected_freezes_within_1_s():
    b = Bench()
    b.run(0, 2)
    frozen = {0: lambda v: sample(0, v[1], (0.001, 0.002, 0.003), (0.1, 0.2, -9.7))}
    b.run(2, 4, override=frozen)
    t_switch = b.first_fed_from(1)
    assert 2.0e6 < t_switch <= 3.0e6
    assert "frozen" in b.sel.reason
    assert {s.imu_id: s.state for s in b.sel.instances()}[0] == "frozen"


def test_noiseless_rest_freezes_everything_and_is_not_a_fault():
    b = Bench()
    still = {i: (lambda v, i=i: sample(i, v[1], (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665))) for i in (0, 1)}
    b.run(0, 3, override=still)
    assert b.sel.selected == 0 and {i for i, _ in b.fed} == {0}


def _noiseless(imu, t_us, gyro, accel, lsb_g=0.001, lsb_a=0.00980665):
    """What ArduPilot's simulator sends: no noise, whole mrad/s and mG."""
    g = tuple(round(x / lsb_g) * lsb_g for x in gyro)
    a = tuple(round(x / lsb_a) * lsb_a for x in accel)
    return sample(imu, t_us, g, a)


def test_noiseless_steady_state_with_one_unit_flickers_does_not_flap():
    """ArduPilot SITL on the ground: RAW_IMU identical for 1.6 s while SCALED_IMU2's z accel flickers by 1 mG in
    about one sample in fifteen. Judged by "the other one changed at all", IMU 0 was "frozen" and ``auto`` flapped
    between IMU 0 and IMU 1 every 2 s."""
    b = Bench()

    def still(v):
        imu, t = v[0], v[1]
        flick = 0.00980665 if imu == 1 and (t // DT_US) % 15 == 7 else 0.0
        return _noiseless(imu, t, (0.0, 0.0, 0.0), (0.05, -0.02, -9.80665 + flick))

    b.run(0, 6, override={0: still, 1: still})
    assert b.sel.selected == 0 and {i for i, _ in b.fed} == {0}
    assert [s.state for s in b.sel.instances()] == ["ok", "ok"]
    assert b.sel.pop_changes()[-1].new == 0 and len(b.sel.pop_changes()) == 0


def test_freeze_of_a_noiseless_imu_caught_while_the_vehicle_turns():
    """Both IMUs noiseless (a simulator); the vehicle yaws at a slowly changing rate: IMU 0 sticks at 2 s."""
    b = Bench()

    def turning(v):
        t = v[1] * 1e-6
        return _noiseless(v[0], v[1], (0.0, 0.0, 0.5 + 0.3 * math.sin(t)), (0.0, 0.0, -9.80665))

    b.run(0, 2, override={0: turning, 1: turning})
    stuck = _noiseless(0, 0, (0.0, 0.0, 0.5 + 0.3 * math.sin(2.0)), (0.0, 0.0, -9.80665))
    b.run(2, 4, override={0: lambda v: (0, v[1], *stuck[2:]), 1: turning})
    t_switch = b.first_fed_from(1)
    assert 2.0e6 < t_switch <= 3.0e6
    assert "instance 0 frozen" in b.sel.reason


def test_freeze_during_a_long_steady_hover_caught_as_soon_as_the_vehicle_moves():
    """Noiseless IMUs through 20 s of steady hover (IMU 1 flickering by one unit now and then); IMU 0 sticks at
    10 s, unnoticeable while nothing changes; the vehicle starts turning at 20 s: caught within 1 s."""
    b = Bench()

    def hover_then_turn(v):
        imu, t = v[0], v[1]
        flick = 0.00980665 if imu == 1 and (t // DT_US) % 15 == 7 else 0.0
        r = 0.0 if t < 20e6 else 0.5 + 0.3 * math.sin(t * 1e-6)
        return _noiseless(imu, t, (0.0, 0.0, r), (0.05, -0.02, -9.80665 + flick))

    b.run(0, 10, override={0: hover_then_turn, 1: hover_then_turn})
    stuck = _noiseless(0, 0, (0.0, 0.0, 0.0), (0.05, -0.02, -9.80665))
    b.run(10, 22, override={0: lambda v: (0, v[1], *stuck[2:]), 1: hover_then_turn})
    t_switch = b.first_fed_from(1)
    assert 20.0e6 < t_switch <= 21.0e6
    assert "instance 0 frozen" in b.sel.reason


def test_frozen_instance_taken_back_only_after_recover_s_of_health():
    """Hysteresis: an instance that freezes again within ``recover_s`` is not switched back to."""
    b = Bench(ImuSelectSettings(recover_s=1.0))
    b.run(0, 1)
    frozen = {0: lambda v: sample(0, v[1], (0.001, 0.002, 0.003), (0.1, 0.2, -9.7))}
    b.run(1, 2, override=frozen)
    assert b.sel.selected == 1
    for t0 in (2.0, 3.5, 5.0):  # alive for 0.5 s, frozen again for 1 s: never healthy long enough
        b.run(t0, t0 + 0.5)
        b.run(t0 + 0.5, t0 + 1.5, override=frozen)
        assert b.sel.selected == 1
    b.run(6.5, 9)  # healthy for good: back to 0 after recover_s (1 s)
    assert b.sel.selected == 0
    back = next(t for i, t in b.fed if i == 0 and t > 6.5e6)
    assert 7.5e6 <= back <= 7.6e6


def test_fail_over_on_saturation_and_back_after_recovery():
    s = ImuSelectSettings(recover_s=1.0)
    b = Bench(s)
    b.run(0, 1)
    sat = {0: lambda v: (*v[:12], GYRO, 0)}
    b.run(1, 1.1, override=sat)
    assert b.sel.selected == 1 and "saturated" in b.sel.reason
    b.run(1.1, 5)  # healthy again: saturation hold 1 s + recovery 1 s, then back to 0
    assert b.sel.selected == 0
    back = [t for i, t in b.fed if i == 0 and t > 1.1e6][0]
    assert 3.0e6 <= back <= 3.3e6


def test_disagreeing_instance_voted_out_with_three():
    b = Bench(n=3)
    b.run(0, 1)
    biased = {0: lambda v: (0, v[1], v[2] + 0.5, *v[3:])}  # 29 °/s off on x
    b.run(1, 3, override=biased)
    t_switch = b.first_fed_from(1)
    assert 1.0e6 < t_switch <= 2.0e6
    assert "disagrees" in b.sel.reason


def test_two_disagreeing_instances_cannot_be_judged():
    b = Bench(n=2)
    biased = {0: lambda v: (0, v[1], v[2] + 0.5, *v[3:])}
    b.run(0, 3, override=biased)
    assert b.sel.selected == 0 and {i for i, _ in b.fed} == {0}


def test_second_instance_freezes_then_saturates_is_reported_within_1_s():
    """Issue 9: the failing instance is detected and the output stays on the healthy one."""
    b = Bench()
    b.run(0, 2)
    frozen = {1: lambda v: sample(1, v[1], (0.01, 0.0, 0.0), (0.0, 0.0, -9.8))}
    for k in range(2 * 400, 3 * 400):
        b.step(k * DT_US, override=frozen)
        if {s.imu_id: s.state for s in b.sel.instances()}[1] == "frozen":
            break
    assert (k * DT_US - 2e6) <= 1e6
    sat = {1: lambda v: sample(1, v[1], (40.0, 0.0, 0.0), (0.0, 0.0, -9.8), sat=GYRO)}
    b.run(3, 3.01, override=sat)
    assert {s.imu_id: s.state for s in b.sel.instances()}[1] == "saturated"
    assert b.sel.selected == 0 and {i for i, _ in b.fed} == {0}


def test_second_message_for_same_instance_is_refused():
    sel = ImuSelector()
    assert sel.observe("RAW_IMU", sample(0, 1000, (0.01, 0, 0), (0, 0, -9.8)))
    assert not sel.observe("SCALED_IMU", sample(0, 1000, (0.01, 0, 0), (0, 0, -9.8)))
    assert sel.duplicate_source == 1


def test_reset_forgets_instances():
    b = Bench()
    b.run(0, 1)
    b.sel.reset()
    assert b.sel.instances() == () and b.sel.selected is None


def test_settings_validation():
    with pytest.raises(ConfigError):
        ImuSelectSettings(imu="3")
    with pytest.raises(ConfigError):
        ImuSelectSettings(stale_s=0)
