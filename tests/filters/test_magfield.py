"""The in-flight magnetometer model (mavahrs.filters.magfield) against firmware_sim's known interference.

firmware_sim's ``mag_anomaly`` scenario: a ground anomaly at take-off, then hover, climbs and descents
while the battery current (SYS_STATUS / BATTERY_STATUS) adds a body field of a known µT per ampere.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from firmware_sim.__main__ import main as sim_main
from mavahrs.evaluation.metrics import summarize
from mavahrs.evaluation.tlogdata import interpolate_attitude
from mavahrs.filters.best import Best, BestSettings
from mavahrs.filters.eskf import EskfSettings
from mavahrs.filters.layout import IN_CURRENT, OUT_Q
from mavahrs.filters.magfield import (
    DISTURBED_GYRO_TEXT,
    DISTURBED_TEXT,
    HEADING_UNKNOWN_SIGMA_DEG,
    HEADING_UNKNOWN_TEXT,
    MagFieldSettings,
    mag_state_text,
)
from mavahrs.replay import ReplaySettings, replay
from mavahrs.replay.engine import _declinate
from mavahrs.sensors.current import battery_current_a

MOTOR_UT_PER_A = (-0.4, 0.2, 0.5)  # ArduPilot's SIM_MAG_MOT of its magnetic flight, in µT/A
ON = BestSettings(eskf=EskfSettings(mag_model=MagFieldSettings(enabled=True)))
OFF = BestSettings(eskf=EskfSettings(mag_model=MagFieldSettings(enabled=False)))


def _anomaly_replay(path, seed: int, duration_s: float = 120.0):  # type: ignore[no-untyped-def]
    """firmware_sim's ``mag_anomaly`` flight (ArduPilot-like magnitudes) written to ``path``, replayed
    with ``best`` and removed."""
    args = ["--tlog", str(path), "--fast", "-q", "--scenario", "mag_anomaly", "--seed", str(seed),
            "--duration", f"{duration_s:g}",
            "--mag-anomaly-ut", "12,-8,15", "--mag-anomaly-height-m", "3",
            "--mag-motor-ut-per-a=" + ",".join(str(v) for v in MOTOR_UT_PER_A), "--hover-current-a", "28"]  # fmt: skip
    assert sim_main(args) == 0
    res = replay(path, ReplaySettings(filters=("best",)))
    path.unlink()
    return res


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    res = _anomaly_replay(tmp_path_factory.mktemp("mag") / "mag_anomaly.tlog", 5)
    truth = next(k for k in res.references if "truth" in k)
    return res, res.references[truth]


def _heading_rms(res, truth, out) -> float:  # type: ignore[no-untyped-def]
    t_ref, q_ref = truth
    q = _declinate(out[:, OUT_Q : OUT_Q + 4].copy(), res.inputs.declination_rad)
    qi = interpolate_attitude(res.inputs.t_us, q, t_ref, max_gap_s=0.5)
    keep = (t_ref >= res.inputs.t_us[0] + 10e6) & np.all(np.isfinite(qi), axis=1)
    return summarize(qi[keep], q_ref[keep]).heading_rms_deg


def _heading_rms_window(res, out, t0_s: float, t1_s: float) -> float:  # type: ignore[no-untyped-def]
    """``best``'s heading RMS against the truth from ``t0_s`` to ``t1_s`` after the first sample, degrees."""
    t_ref, q_ref = res.references[next(k for k in res.references if "truth" in k)]
    q = _declinate(out[:, OUT_Q : OUT_Q + 4].copy(), res.inputs.declination_rad)
    qi = interpolate_attitude(res.inputs.t_us, q, t_ref, max_gap_s=0.5)
    tr = (t_ref - res.inputs.t_us[0]) * 1e-6
    keep = (tr >= t0_s) & (tr <= t1_s) & np.all(np.isfinite(qi), axis=1)
    assert keep.sum() > 10
    return summarize(qi[keep], q_ref[keep]).heading_rms_deg


def test_current_reaches_the_rows(flight) -> None:  # type: ignore[no-untyped-def]
    res, _ = flight
    cur = res.inputs.rows[:, IN_CURRENT]
    assert np.isfinite(cur).mean() > 0.95  # SYS_STATUS at 5 Hz: held between messages
    assert np.nanmax(cur) > 20.0 and np.nanmin(cur) < 1.0  # hover ~28 A, on the ground avionics only


def test_learns_the_field_per_ampere_and_holds_heading(flight) -> None:  # type: ignore[no-untyped-def]
    res, truth = flight
    on = Best(ON)
    out_on = res.inputs.run_filter(on)
    state = on.mag_model_state()
    assert state is not None
    np.testing.assert_allclose(state["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.12)
    assert state["disturbances"] >= 1  # the anomaly on the ground / its end at take-off was noticed
    off = Best(BestSettings(eskf=EskfSettings(mag_model=MagFieldSettings(enabled=False))))
    out_off = res.inputs.run_filter(off)
    assert off.mag_model_state() is None
    head_on, head_off = _heading_rms(res, truth, out_on), _heading_rms(res, truth, out_off)
    print(f"heading RMS: model on {head_on:.2f}°, off {head_off:.2f}°")
    # measured (seed 5, 120 s): model on 4.2°, off 3.3° (most of it on the ground in the anomaly and
    # just after take-off) with the model's former defaults; bounds that catch a regression only
    assert head_on < 4.5, (head_on, head_off)
    assert head_off < 4.5, (head_on, head_off)
    assert head_on < head_off + 0.3, (head_on, head_off)  # on by default: no worse than off


def test_status_says_disturbed_in_the_anomaly(flight) -> None:  # type: ignore[no-untyped-def]
    """On the ground in the anomaly the field disagrees with the WMM from the first sample: the compass is
    not used, the heading is the disturbed compass's start-up alignment with its 1-σ open, and the status
    says the heading is unknown; once GNSS velocity has told the heading (the first horizontal
    accelerations after take-off) it says GNSS holds it, and the heading is then near the truth.  With the
    model on (an autopilot's stream): its state and offsets."""
    res, truth = flight
    t = (res.inputs.t_us - res.inputs.t_us[0]) * 1e-6
    off = Best(OFF)
    i8 = int(np.searchsorted(t, 8.0))
    outs = [res.inputs.run_filter(off, 0, i8)]  # as the pipeline runs it (WMM reference)
    st = off.mag_status()
    assert st["state"] == "disturbed" and st["model"] == "off" and st["heading_from"] == "unknown", st
    assert st["filter_heading_sigma_deg"] >= HEADING_UNKNOWN_SIGMA_DEG, st
    assert mag_state_text(st) == HEADING_UNKNOWN_TEXT
    # wait for the heading to become known (GNSS), in 0.5 s steps as a status reader polls
    i0, known_at = i8, None
    while i0 < len(t) - 1 and t[i0] < 60.0:
        i1 = int(np.searchsorted(t, t[i0] + 0.5))
        outs.append(res.inputs.run_filter(off, i0, i1))
        i0 = i1
        st = off.mag_status()
        if st["heading_from"] != "unknown":
            known_at = t[i1 - 1]
            break
    assert known_at is not None, "the heading was still unknown 60 s into the flight"
    assert 10.0 < known_at < 40.0, known_at  # after take-off (10 s), within the first manoeuvres
    if st["state"] == "disturbed":
        assert mag_state_text(st) == DISTURBED_TEXT
    # the heading the status now calls known is near the truth (error in its last 0.5 s)
    out = np.concatenate(outs)
    t_ref, q_ref = truth
    decl = res.inputs.declination_rad
    q = _declinate(out[:, OUT_Q : OUT_Q + 4].copy(), decl[: len(out)] if np.ndim(decl) else decl)
    qi = interpolate_attitude(res.inputs.t_us[: len(out)], q, t_ref, max_gap_s=0.5)
    tr = (t_ref - res.inputs.t_us[0]) * 1e-6
    keep = (tr > known_at - 0.5) & (tr <= known_at) & np.all(np.isfinite(qi), axis=1)
    err = summarize(qi[keep], q_ref[keep]).heading_rms_deg
    print(f"heading unknown until {known_at:.1f} s; heading error then {err:.1f}°")
    assert err < 10.0, (known_at, err)
    # the replay header says it too, with until when (the replay's best: the model on)
    note = next((n for n in res.notes if HEADING_UNKNOWN_TEXT in n), None)
    assert note is not None and note.startswith("best: "), res.notes
    on = Best(ON)
    res.inputs.run_filter(on)
    st_on = on.mag_status()
    assert st_on["model"] == "on" and len(st_on["offset_ut"]) == 3 and "declination_correction_deg" in st_on


def test_saved_model_resets_the_unknown_heading_after_take_off(flight, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A model saved from another flight of the same vehicle (its field per ampere) sets the heading that
    the ground anomaly left unknown once the vehicle is in the air, before any horizontal acceleration:
    the status says the heading is known, and it is near the truth; without it the heading stays unknown."""
    res, truth = flight
    prev = _anomaly_replay(tmp_path / "other.tlog", 3)
    first = Best(ON)
    prev.inputs.run_filter(first)
    saved = first.export_mag_model()
    assert saved is not None
    t = (res.inputs.t_us - res.inputs.t_us[0]) * 1e-6
    i14 = int(np.searchsorted(t, 14.0))  # take-off at 10 s; the first horizontal accelerations after 16 s
    fresh, loaded = Best(ON), Best(ON)
    assert loaded.load_mag_model(saved) is None
    out_fresh = res.inputs.run_filter(fresh, 0, i14)
    out = res.inputs.run_filter(loaded, 0, i14)
    st = loaded.mag_status()
    assert st["heading_from"] != "unknown" and st["filter_heading_sigma_deg"] < 15.0, st
    t_ref, q_ref = truth
    decl = res.inputs.declination_rad
    tr = (t_ref - res.inputs.t_us[0]) * 1e-6

    def err_13_14(o):  # type: ignore[no-untyped-def]
        q = _declinate(o[:, OUT_Q : OUT_Q + 4].copy(), decl[: len(o)] if np.ndim(decl) else decl)
        qi = interpolate_attitude(res.inputs.t_us[: len(o)], q, t_ref, max_gap_s=0.5)
        keep = (tr > 13.0) & (tr <= t[i14 - 1]) & np.all(np.isfinite(qi), axis=1)
        return summarize(qi[keep], q_ref[keep]).heading_rms_deg

    err, err_fresh = err_13_14(out), err_13_14(out_fresh)
    print(f"heading error 13-14 s: loaded model {err:.1f}° (σ {st['filter_heading_sigma_deg']}°), fresh {err_fresh:.1f}°")
    # measured: loaded 0.9° (σ 6.8°), fresh 9.9° (the anomaly's start-up alignment, σ ≥ 30°) before the
    # take-off fit; since, the fresh model's heading is reset at 12–13 s too (13–14 s: fresh 8.2°, loaded 1.8°)
    assert err < 3.0, (err, err_fresh)


def test_fresh_model_learns_in_the_air_and_resets_the_unknown_heading(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Without a saved model: once the vehicle is above the ground anomaly, the pair updates (a reading
    against one taken earlier, related by the rotation between them) learn the field per ampere on every
    axis from the current's changes, the corrected reading then resets the heading the anomaly left
    unknown — before GNSS can tell it (seed 29: the first horizontal accelerations at 25 s; before the
    pair updates the heading was unknown until 27 s, 13–18° off from take-off)."""
    res = _anomaly_replay(tmp_path / "seed29.tlog", 29, 45.0)
    truth = next(k for k in res.references if "truth" in k)
    t_ref, q_ref = res.references[truth]
    t = (res.inputs.t_us - res.inputs.t_us[0]) * 1e-6
    tr = (t_ref - res.inputs.t_us[0]) * 1e-6
    decl = res.inputs.declination_rad
    fresh = Best(ON)
    i0, known_at, outs = 0, None, []
    while i0 < len(t) - 1:  # poll the status every 0.5 s as a reader would
        i1 = int(np.searchsorted(t, t[i0] + 0.5))
        outs.append(res.inputs.run_filter(fresh, i0, i1))
        i0 = i1
        if t[i1 - 1] > 10.0 and fresh.mag_status()["heading_from"] != "unknown":
            known_at = t[i1 - 1]
            break
    # known at 18 s with the pair updates alone (one pair per 2 s), at 13–14 s with the take-off fit
    assert known_at is not None and known_at < 16.0, known_at
    state = fresh.mag_model_state()
    assert state is not None
    np.testing.assert_allclose(state["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.1)
    # the earth field was not pulled by the anomaly at take-off (the WMM's: ≈ 23.6 µT across, −53.1 down)
    wmm = res.inputs.mag_reference_events[0]
    assert abs(state["earth_field_ut"]["down"] - wmm[1] * math.sin(wmm[2])) < 2.0, state
    # the heading it is now known with is near the truth (the 1 s after)
    i2 = int(np.searchsorted(t, known_at + 1.0))
    outs.append(res.inputs.run_filter(fresh, i0, i2))
    out = np.concatenate(outs)
    q = _declinate(out[:, OUT_Q : OUT_Q + 4].copy(), decl[: len(out)] if np.ndim(decl) else decl)
    qi = interpolate_attitude(res.inputs.t_us[: len(out)], q, t_ref, max_gap_s=0.5)
    keep = (tr > known_at) & (tr <= t[i2 - 1]) & np.all(np.isfinite(qi), axis=1)
    err = summarize(qi[keep], q_ref[keep]).heading_rms_deg
    print(f"heading known at {known_at:.1f} s, error in the next 1 s {err:.1f}°, model {state}")
    # measured: known at 17.5 s, 1.1° (the pair updates off: unknown until 27 s, 13–18° off until then)
    assert err < 5.0, (known_at, err)


def test_take_off_fit_tells_the_heading_soon_after_lift_off(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A start in a ground anomaly, no saved model (seed 11: the compass's start-up alignment 28–31° off):
    the take-off fit (readings near the ground against one held before the current rose, the anomaly's
    fade with height fitted beside the field per ampere) gives the field per ampere from 1 m up (at 1.9 m,
    11.6 s), and the corrected reading, the fitted anomaly taken out, resets the heading.  Before it the
    heading stayed 28–31° off until 17 s (the first current change above 5 m), 29° RMS over 14–17 s."""
    res = _anomaly_replay(tmp_path / "seed11.tlog", 11, 30.0)
    fresh = Best(ON)
    out = res.inputs.run_filter(fresh)
    err = _heading_rms_window(res, out, 14.0, 17.0)
    state = fresh.mag_model_state()
    assert state is not None
    print(f"heading RMS 14-17 s: {err:.1f} deg; k {state['motor_ut_per_a']} (true {MOTOR_UT_PER_A})")
    # measured: 3.9° (k −0.40, 0.21, 0.51 µT/A from the fit, true −0.4, 0.2, 0.5)
    assert err < 8.0, err
    np.testing.assert_allclose(state["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.1)
    fit = state["takeoff_fit"]  # what the fit gave, as /status.json shows it
    assert isinstance(fit, dict)
    np.testing.assert_allclose(fit["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.1)



def test_take_off_fit_resets_the_heading_within_a_second_of_lift_off(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Seed 11 (the compass's start-up alignment 28° off in the ground anomaly, lift-off at 10.5 s): the heading
    reset from the take-off fit's corrected reading waited for 0.5 s of readings fitting the WMM's norm and dip
    (``_RESET_FIT_S``) and came at 12 s, 24° RMS over 11.5–12.5 s (the 200 s flight: 3.04° overall, the only
    seed of 18 above 3°).  It now comes after 0.2 s, and below the ground's reach the corrected reading (the
    fitted anomaly faded to the height taken out) keeps correcting the heading with the fit's σ
    (``MF_TO_HVAR``), which recovers what the earlier, lower reset loses (docs/accuracy.md, branch anom4)."""
    res = _anomaly_replay(tmp_path / "seed11.tlog", 11, 30.0)
    fresh = Best(ON)
    out = res.inputs.run_filter(fresh)
    err = _heading_rms_window(res, out, 11.5, 12.5)
    print(f"heading RMS 11.5-12.5 s: {err:.1f} deg")
    # measured: see docs/accuracy.md "Seventh round (branch anom4)"
    assert err < 12.0, err


def test_take_off_fit_measures_the_fade_from_the_ground_it_lifted_off(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The take-off fit's anomaly fades with the height above the ground the vehicle lifted off from.  Seed 41:
    the integrated velocity wandered on the ground, and its lowest point since the start was 0.18 m below the
    ground at lift-off; measured from there, the fit took the anomaly as 23 % faded before the vehicle moved and
    gave k = (−0.48, 0.33, 0.66) µT/A (true −0.4, 0.2, 0.5): the heading reset 9° off (−8.9° at 13–16 s on the
    200 s flight; this 20 s flight fails the k check before the change).  From the lowest height since the
    reference was held: k within 0.06, the heading 2.9° RMS at 13–16 s."""
    res = _anomaly_replay(tmp_path / "seed41.tlog", 41, 20.0)
    fresh = Best(ON)
    out = res.inputs.run_filter(fresh)
    state = fresh.mag_model_state()
    assert state is not None
    fit = state["takeoff_fit"]
    assert isinstance(fit, dict)
    print(f"take-off fit {fit}")
    # measured: (−0.43, 0.25, 0.55) µT/A, residual 0.6 µT
    np.testing.assert_allclose(fit["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.08)
    err = _heading_rms_window(res, out, 13.0, 16.0)
    print(f"heading RMS 13-16 s: {err:.1f} deg")
    # measured: 2.9° (the 200 s flight before the change: 8.9°)
    assert err < 5.0, err


def test_model_kept_across_a_restart(flight) -> None:  # type: ignore[no-untyped-def]
    res, truth = flight
    first = Best(ON)
    res.inputs.run_filter(first)
    saved = first.export_mag_model()
    assert saved is not None and saved["format"] == 1
    np.testing.assert_allclose(saved["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.12)
    assert Best(ON).export_mag_model() is None  # nothing learnt: nothing to write over a saved file
    assert Best(OFF).export_mag_model() is None and Best(OFF).mag_model_state() is None
    assert Best().mag_model_state() is None  # the Python API's default (a raw IMU): off
    vehicle = Best()
    vehicle.set_vehicle_stream()
    assert vehicle.mag_model_state() is not None  # an autopilot's stream: on unless set either way
    second = Best(ON)
    assert second.load_mag_model(saved) is None
    np.testing.assert_allclose(second.mag_model_state()["motor_ut_per_a"], saved["motor_ut_per_a"], atol=1e-3)
    out = res.inputs.run_filter(second)  # the reference seeding and the re-initialisation keep it
    np.testing.assert_allclose(second.mag_model_state()["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.12)
    assert _heading_rms(res, truth, out) < 5.5
    for bad in (None, {"format": 2}, {"format": 1, "offset_ut": [0, 0], "motor_ut_per_a": [0, 0, 0],
                                      "motor_sigma_ut_per_a": [0, 0, 0]},
                {"format": 1, "offset_ut": [0, 0, 0], "motor_ut_per_a": [math.nan, 0, 0],
                 "motor_sigma_ut_per_a": [0, 0, 0]}):  # fmt: skip
        assert isinstance(Best(ON).load_mag_model(bad), str)


def test_replay_says_when_the_compass_is_not_used(flight) -> None:  # type: ignore[no-untyped-def]
    res, _ = flight
    assert any(DISTURBED_TEXT in n for n in res.notes), res.notes


def test_status_text() -> None:
    assert mag_state_text(None) == ""
    assert mag_state_text({"state": "disturbed"}) == DISTURBED_TEXT
    text = mag_state_text(
        {"state": "trusted", "offset_ut": [0.2, -1.3, 0.7], "motor_ut_per_a": [-0.4, 0.2, 0.5]}
    )
    assert text.startswith("mag trusted") and "-0.40" in text
    assert mag_state_text({"state": "disturbed", "heading_from": "gyro"}) == DISTURBED_GYRO_TEXT
    assert mag_state_text({"state": "trusted", "model": "off", "declination_correction_deg": 0.0}) == "mag trusted"
    text = mag_state_text({"state": "trusted", "declination_correction_deg": -0.52, "declination_sigma_deg": 0.26})
    assert text == "mag trusted, declination -0.52 ± 0.26° from the WMM's"


def test_battery_current_parsing() -> None:
    assert battery_current_a(SimpleNamespace(current_battery=2850)) == pytest.approx(28.5)
    assert battery_current_a(SimpleNamespace(current_battery=-1)) is None  # not measured
    assert battery_current_a(SimpleNamespace()) is None
    assert battery_current_a(SimpleNamespace(current_battery=math.nan)) is None


def test_settings_validated() -> None:
    with pytest.raises(ValueError):
        MagFieldSettings(noise_ut=0.0)
    with pytest.raises(ValueError):
        MagFieldSettings(hold_s=-1.0)


def test_an_infinite_current_reading_is_not_known_current(flight) -> None:  # type: ignore[no-untyped-def]
    """A corrupt battery current of ±inf passed the model's "known" test (``amps == amps`` holds for inf) and
    went into the field per ampere: 2 % of the rows at +inf cost a `mag_anomaly` flight 2.97 → 4.69° of heading
    (measured on seed 3, 40 s).  ±inf is now "not known", as NaN: the heading and the learnt motor field as on
    the clean rows."""
    from dataclasses import replace

    res, truth = flight
    clean = Best(ON)
    head_clean = _heading_rms(res, truth, res.inputs.run_filter(clean))
    rows = res.inputs.rows.copy()
    bad = np.random.default_rng(3).choice(rows.shape[0], rows.shape[0] // 50, replace=False)
    rows[bad[::2], IN_CURRENT] = np.inf
    rows[bad[1::2], IN_CURRENT] = -np.inf
    corrupt = Best(ON)
    out = replace(res.inputs, rows=rows).run_filter(corrupt)
    assert np.isfinite(out[:, OUT_Q : OUT_Q + 4]).all()
    head_bad = _heading_rms(res, truth, out)
    assert head_bad < head_clean + 0.3, (head_bad, head_clean)
    state = corrupt.mag_model_state()
    assert state is not None
    np.testing.assert_allclose(state["motor_ut_per_a"], MOTOR_UT_PER_A, atol=0.12)
