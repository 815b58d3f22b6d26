"""World Magnetic Model access, true-north re-referencing and the live declination source.

Test values are NOAA's published ones: the WMM2025 report's test-value table
(declination), rows of NOAA's WMM2025 validation file (D, I, F) and the
WMM2020 report's table (X, Y, Z, F, I, D), each checked to its published
precision (half a unit of the last printed digit).
"""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace

import numpy as np
import pytest

from mavahrs.filters.gains import GainScheduleSettings
from mavahrs.geometry.quaternion import multiply, random_unit, rotate
from mavahrs.geometry.rotation import to_euler_rad
from mavahrs.sensors.geomag import (
    DeclinationSource,
    MagneticFieldSettings,
    apply_declination,
    apply_declination_wxyz,
    decimal_year_from_unix_s,
    distance_km,
    expected_field,
    field_from_angles,
    rotate_true_to_magnetic,
)

# WMM2025 report (NOAA/NCEI, Dec 2024), test values: year, height km, lat, lon, D deg.
WMM2025_REPORT_DECLINATION = [
    (2025.0, 0, 80, 0, 1.28), (2025.0, 0, 0, 120, -0.16), (2025.0, 0, -80, 240, 68.78),
    (2025.0, 100, 80, 0, 0.85), (2025.0, 100, 0, 120, -0.15), (2025.0, 100, -80, 240, 68.21),
    (2027.5, 0, 80, 0, 2.59), (2027.5, 0, 0, 120, -0.24), (2027.5, 0, -80, 240, 68.49),
    (2027.5, 100, 80, 0, 2.16), (2027.5, 100, 0, 120, -0.23), (2027.5, 100, -80, 240, 67.93),
]  # fmt: skip

# NOAA's WMM2025 validation vectors (CIRES-Geomagnetism/wmm, WMM2025_FINAL_TEST_VALUES.txt):
# year, height km, lat, lon, D deg, I deg, F nT.
WMM2025_VALIDATION = [
    (2025.0, 28, 89, -121, -99.77, 88.47, 56214),
    (2025.0, 65, 43, 93, 0.50, 64.10, 55627),
    (2025.5, 69, 38, -144, 12.93, 56.97, 42374),
    (2026.0, 82, -64, 87, -81.74, -75.40, 55453),
    (2026.5, 12, -79, 115, -137.58, -77.37, 59546),
    (2027.5, 0, -13, -59, -17.49, -15.26, 23220),
    (2028.5, 55, 86, 70, 67.64, 87.57, 55976),
    (2029.0, 50, 87, -154, -73.48, 89.07, 56000),
]  # fmt: skip

# WMM2020 report test values: year, height km, lat, lon, X, Y, Z, F (nT), I, D (deg).
WMM2020_REPORT = [
    (2020.0, 0, 80, 0, 6570.4, -146.3, 54606.0, 55000.1, 83.14, -1.28),
    (2020.0, 0, 0, 120, 39624.3, 109.9, -10932.5, 41104.9, -15.42, 0.16),
    (2022.5, 0, -80, 240, 6016.5, 15776.7, -52251.6, 54912.1, -72.09, 69.13),
    (2022.5, 100, 0, 120, 37694.0, -35.3, -10362.0, 39092.4, -15.37, -0.05),
]  # fmt: skip

ANGLE_TOL_DEG = 0.0051  # published to 0.01°


@pytest.mark.parametrize("year,h_km,lat,lon,d_deg", WMM2025_REPORT_DECLINATION)
def test_declination_matches_wmm2025_report(year: float, h_km: float, lat: float, lon: float, d_deg: float) -> None:
    f = expected_field(lat, lon, h_km * 1000.0, year)
    assert math.degrees(f.declination_rad) == pytest.approx(d_deg, abs=ANGLE_TOL_DEG)
    assert f.source == "WMM-2025" and f.within_model_lifespan


@pytest.mark.parametrize("year,h_km,lat,lon,d_deg,i_deg,f_nt", WMM2025_VALIDATION)
def test_field_matches_noaa_validation_vectors(
    year: float, h_km: float, lat: float, lon: float, d_deg: float, i_deg: float, f_nt: float
) -> None:
    f = expected_field(lat, lon, h_km * 1000.0, year)
    assert f.declination_deg == pytest.approx(d_deg, abs=ANGLE_TOL_DEG)
    assert f.inclination_deg == pytest.approx(i_deg, abs=ANGLE_TOL_DEG)
    assert f.strength_ut * 1000.0 == pytest.approx(f_nt, abs=0.51)  # published to 1 nT


@pytest.mark.parametrize("year,h_km,lat,lon,x,y,z,f_nt,i_deg,d_deg", WMM2020_REPORT)
def test_older_logs_use_the_model_of_their_date(
    year: float, h_km: float, lat: float, lon: float, x: float, y: float, z: float, f_nt: float, i_deg: float, d_deg: float
) -> None:
    f = expected_field(lat, lon, h_km * 1000.0, year)
    assert f.source == "WMM-2020"
    np.testing.assert_allclose(np.array(f.north_east_down_ut) * 1000.0, [x, y, z], atol=0.051)
    assert f.strength_ut * 1000.0 == pytest.approx(f_nt, abs=0.051)
    assert f.inclination_deg == pytest.approx(i_deg, abs=ANGLE_TOL_DEG)
    assert f.declination_deg == pytest.approx(d_deg, abs=ANGLE_TOL_DEG)


def test_field_vector_agrees_with_its_angles() -> None:
    f = expected_field(47.4, 8.5, 500.0, 2026.3)
    n, e, d = f.north_east_down_ut
    assert math.hypot(n, e, d) == pytest.approx(f.strength_ut, rel=1e-9)
    assert math.atan2(e, n) == pytest.approx(f.declination_rad, abs=1e-9)
    assert math.atan2(d, math.hypot(n, e)) == pytest.approx(f.inclination_rad, abs=1e-9)
    g = field_from_angles(f.declination_rad, f.inclination_rad, f.strength_ut)
    np.testing.assert_allclose(g.north_east_down_ut, f.north_east_down_ut, atol=1e-9)


def test_dates_outside_the_bundled_models_are_extrapolated_and_flagged() -> None:
    f = expected_field(47.4, 8.5, 0.0, 2031.0)
    assert not f.within_model_lifespan and f.source == "WMM-2025"
    g = expected_field(47.4, 8.5, 0.0, 2029.9)
    assert abs(f.declination_deg - g.declination_deg) < 1.0  # a slow secular change, not garbage


@pytest.mark.parametrize("bad", [(91.0, 0.0, 0.0, 2026.0), (float("nan"), 0.0, 0.0, 2026.0), (0.0, 0.0, 2e6, 2026.0)])
def test_invalid_arguments_raise(bad: tuple[float, float, float, float]) -> None:
    with pytest.raises(ValueError):
        expected_field(*bad)


def test_longitude_is_wrapped() -> None:
    a = expected_field(-80.0, 240.0, 0.0, 2025.0)
    b = expected_field(-80.0, -120.0, 0.0, 2025.0)
    assert a.declination_rad == pytest.approx(b.declination_rad, abs=1e-12)


# --------------------------------------------------------------------------- true north


def test_apply_declination_adds_declination_to_yaw_only(rng: np.random.Generator) -> None:
    q = random_unit(200, rng)
    d = math.radians(12.0)
    q_true = apply_declination(q, d)
    e_mag = to_euler_rad(q)
    e_true = to_euler_rad(q_true)
    ok = np.abs(e_mag[:, 1]) < math.radians(80)  # away from gimbal lock
    np.testing.assert_allclose(e_true[ok, :2], e_mag[ok, :2], atol=1e-9)
    dyaw = np.angle(np.exp(1j * (e_true[ok, 2] - e_mag[ok, 2])))
    np.testing.assert_allclose(dyaw, d, atol=1e-9)
    # Same as rotating the earth-frame result of every body vector by R_z(D).
    v = rng.normal(size=(200, 3))
    r = np.array([math.cos(d / 2), 0, 0, math.sin(d / 2)])
    np.testing.assert_allclose(rotate(q_true, v), rotate(r, rotate(q, v)), atol=1e-12)
    np.testing.assert_allclose(q_true, multiply(r, q), atol=1e-15)


def test_apply_declination_scalar_equals_vectorised_and_per_row(rng: np.random.Generator) -> None:
    q = random_unit(50, rng)
    d = rng.uniform(-math.pi, math.pi, 50)
    out = apply_declination(q, d)
    for i in range(50):
        np.testing.assert_allclose(apply_declination_wxyz(*q[i], d[i]), out[i], atol=1e-15)
    np.testing.assert_allclose(apply_declination(q[3], d[3]), out[3], atol=1e-15)
    np.testing.assert_allclose(apply_declination(apply_declination(q, d), -d), q, atol=1e-12)


def test_magnetometer_heading_becomes_true_heading() -> None:
    """A level vehicle facing true north sees the field D west of its nose; after correction, yaw 0."""
    field = expected_field(-35.36, 149.17, 600.0, 2026.0)  # Canberra-like: D ≈ +12°
    d = field.declination_rad
    assert 10.0 < math.degrees(d) < 14.0
    # Mag-referenced estimate: yaw = −D (the nose is D west of magnetic north).
    q_mag = np.array([math.cos(-d / 2), 0.0, 0.0, math.sin(-d / 2)])
    q_true = apply_declination(q_mag, d)
    assert to_euler_rad(q_true)[2] == pytest.approx(0.0, abs=1e-12)


def test_rotate_true_to_magnetic_is_the_inverse_frame_rotation() -> None:
    d = math.radians(12.0)
    # A velocity pointing at magnetic north (azimuth D in true NED) is (v, 0) in magnetic NED.
    n, e = rotate_true_to_magnetic(10 * math.cos(d), 10 * math.sin(d), d)
    assert (n, e) == pytest.approx((10.0, 0.0), abs=1e-12)


# --------------------------------------------------------------------------- helpers


def test_decimal_year() -> None:
    assert decimal_year_from_unix_s(1767225600.0) == pytest.approx(2026.0)  # 2026-01-01T00:00Z
    assert decimal_year_from_unix_s(1767225600.0 + 365 * 86400 / 2) == pytest.approx(2026.5)


def test_distance_km() -> None:
    assert distance_km(0, 0, 0, 1) == pytest.approx(111.195, abs=0.01)
    assert distance_km(47, 8, 47, 8) == 0.0


# --------------------------------------------------------------------------- settings and source


@pytest.mark.parametrize(
    "kwargs",
    [
        {"declination_deg": 200.0},
        {"inclination_deg": -91.0},
        {"strength_ut": 0.0},
        {"latitude_deg": 10.0},
        {"update_distance_km": 0.0},
        {"declination_deg": float("nan")},
    ],
)
def test_settings_validation(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        MagneticFieldSettings(**kwargs)  # type: ignore[arg-type]


def _msg(kind: str, **fields: float) -> SimpleNamespace:
    return SimpleNamespace(get_type=lambda: kind, **fields)


def _gpi(lat: float, lon: float, alt_m: float = 100.0) -> SimpleNamespace:
    return _msg("GLOBAL_POSITION_INT", lat=round(lat * 1e7), lon=round(lon * 1e7), alt=round(alt_m * 1000))


def test_source_unknown_until_position_then_wmm() -> None:
    src = DeclinationSource(MagneticFieldSettings(), decimal_year=2026.0)
    assert src.declination_rad == 0.0 and src.field is None and not src.known
    assert "unknown" in src.status()
    assert not src.handle(_gpi(0.0, 0.0))  # zeros = no fix yet
    assert not src.handle(_msg("GPS_RAW_INT", lat=int(-35.36e7), lon=int(149.17e7), alt=600000, fix_type=1))
    assert src.handle(_gpi(-35.36, 149.17, 600.0))
    ref = expected_field(-35.36, 149.17, 600.0, 2026.0)
    assert src.declination_rad == pytest.approx(ref.declination_rad, abs=1e-6)
    assert src.known and "WMM-2025" in src.status()


def test_source_recomputes_only_after_moving_far_enough() -> None:
    src = DeclinationSource(MagneticFieldSettings(update_distance_km=5.0), decimal_year=2026.0)
    assert src.handle(_gpi(47.0, 8.0))
    n0 = src.changes
    for k in range(200):  # wander within ~2 km: no recomputation
        assert not src.handle(_gpi(47.0 + 0.00002 * k * math.sin(k), 8.0 + 0.0001 * (k % 20)))
    assert src.changes == n0
    assert src.handle(_msg("GPS_RAW_INT", lat=int(47.1e7), lon=int(8.0e7), alt=500000, fix_type=3))  # 11 km north
    assert src.changes == n0 + 1


def test_source_date_from_system_time_and_home_position() -> None:
    src = DeclinationSource(MagneticFieldSettings())  # no date yet
    assert not src.handle(_msg("HOME_POSITION", latitude=int(40e7), longitude=int(-105e7), altitude=1600000))
    assert src.field is None and "no date" in src.status()
    assert not src.handle(_msg("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=0))  # no GPS time yet
    assert src.handle(_msg("SYSTEM_TIME", time_unix_usec=int(1767225600e6), time_boot_ms=0))
    ref = expected_field(40.0, -105.0, 1600.0, 2026.0)
    assert src.field is not None and src.field.declination_rad == pytest.approx(ref.declination_rad, abs=1e-6)
    # A live fix takes precedence over the home position afterwards.
    assert src.handle(_gpi(-35.0, 149.0))
    assert not src.handle(_msg("HOME_POSITION", latitude=int(40e7), longitude=int(-105e7), altitude=1600000))


def test_manual_settings() -> None:
    fixed = DeclinationSource(MagneticFieldSettings(declination_deg=12.0), decimal_year=2026.0)
    assert fixed.declination_rad == pytest.approx(math.radians(12.0)) and fixed.known
    assert fixed.field is None  # no inclination/strength: no full field
    fixed.handle(_gpi(47.0, 8.0))
    assert fixed.declination_rad == pytest.approx(math.radians(12.0))  # manual wins over the model...
    assert fixed.field is not None and fixed.field.strength_ut > 40.0  # ...model fills the rest
    full = DeclinationSource(MagneticFieldSettings(declination_deg=-3.0, inclination_deg=60.0, strength_ut=48.0))
    assert full.field is not None and full.field.strength_ut == 48.0
    placed = DeclinationSource(
        MagneticFieldSettings(latitude_deg=-35.36, longitude_deg=149.17, decimal_year=2026.0)
    )
    assert placed.declination_rad == pytest.approx(expected_field(-35.36, 149.17, 0.0, 2026.0).declination_rad)
    magnetic = DeclinationSource(MagneticFieldSettings(true_north=False), decimal_year=2026.0)
    magnetic.handle(_gpi(-35.36, 149.17))
    assert magnetic.declination_rad == 0.0 and magnetic.field is not None and magnetic.status() == "magnetic north"


def test_gain_schedule_seeded_from_the_model() -> None:
    base = GainScheduleSettings()
    src = DeclinationSource(MagneticFieldSettings(), decimal_year=2026.0)
    assert src.gain_schedule(base) is base
    src.handle(_gpi(-35.36, 149.17))
    seeded = src.gain_schedule(base)
    assert src.field is not None
    assert seeded.mag_reference_norm_ut == pytest.approx(src.field.strength_ut)
    assert seeded.mag_reference_dip_rad == pytest.approx(src.field.inclination_rad)
    assert seeded.mag_reference_dip_rad < 0  # southern hemisphere: field points up
    assert src.mag_reference() == (src.field.strength_ut, src.field.inclination_rad)
    off = DeclinationSource(MagneticFieldSettings(seed_gain_schedule=False), decimal_year=2026.0)
    off.handle(_gpi(-35.36, 149.17))
    assert off.gain_schedule(base) is base and off.mag_reference() is None


def test_model_seeded_reference_rejects_a_disturbance_present_from_the_start() -> None:
    """With the model's field, a magnet already near the sensor at start-up is recognised at once;
    without it, the schedule learns the disturbed field as its reference."""
    from mavahrs.filters import create

    src = DeclinationSource(MagneticFieldSettings(), decimal_year=2026.0)
    src.handle(_gpi(-35.36, 149.17, 600.0))
    f = src.field
    assert f is not None
    # Level, facing magnetic north: body field = (H, 0, Z) in the filter's magnetic frame; +25 % disturbance.
    h = f.strength_ut * math.cos(f.inclination_rad)
    z = f.strength_ut * math.sin(f.inclination_rad)
    mag = np.array([h, 0.0, z]) * 1.25
    accel = np.array([0.0, 0.0, -9.80665])

    def mag_weights(seed: bool) -> list[float]:
        filt = create("mahony")
        ref = src.mag_reference()
        if seed and ref is not None:  # what the pipeline does when the field becomes known
            filt.set_mag_reference(*ref)
        weights = []
        for _ in range(800):  # 8 s at 100 Hz, past the 3 s start-up boost
            filt.update(np.zeros(3), accel, mag, dt_s=0.01)
            weights.append(filt.diagnostics.mag_weight)
        return weights

    assert min(mag_weights(seed=False)[1:]) > 0.99  # (sample 0 initialises the filter)
    seeded = mag_weights(seed=True)
    assert max(seeded[400:]) < 0.01  # rejected as soon as the start-up boost is over
    filt = create("mahony")
    filt.set_mag_reference(f.strength_ut, f.inclination_rad)
    assert filt.settings.schedule.mag_reference_norm_ut == f.strength_ut
    with pytest.raises(ValueError):
        filt.set_mag_reference(-1.0, 0.0)


def test_field_is_logged_once_when_a_new_date_changes_it_by_hundredths(caplog: pytest.LogCaptureFixture) -> None:
    # the daemon starts with today's date; the autopilot's SYSTEM_TIME (a year earlier) moves the
    # declination at Canberra by ~0.03°: one line, with the value as it reads at 0.1°
    caplog.set_level(logging.DEBUG, logger="mavahrs.sensors.geomag")
    src = DeclinationSource(MagneticFieldSettings(), decimal_year=2026.9)
    assert src.handle(_gpi(-35.3633, 149.1652, 584.0))
    assert src.set_decimal_year(2025.9)
    info = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert info == ["magnetic field from WMM-2025 at -35.3633, 149.1652: declination 12.7°, inclination -66.0°, 58.1 µT"]
    assert len([r for r in caplog.records if r.levelno == logging.DEBUG and "magnetic field" in r.getMessage()]) == 1
    # a real change (another place) is logged again
    assert src.handle(_gpi(47.0, 8.0))
    assert len([r for r in caplog.records if r.levelno == logging.INFO]) == 2
