"""Earth-frame conversions and the 24 sensor-axis remaps."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mavahrs.geometry import quaternion as qm
from mavahrs.geometry.frames import AXIS_REMAPS, convert_earth_frame, remap, remap_matrix


def _ned_to(frame: str, v_ned: np.ndarray) -> np.ndarray:
    """The same physical vectors written in ENU or NWU components."""
    n, e, d = np.moveaxis(v_ned, -1, 0)
    if frame == "ENU":
        return np.stack([e, n, -d], axis=-1)
    if frame == "NWU":
        return np.stack([n, -e, -d], axis=-1)
    return v_ned


@pytest.mark.parametrize("frame", ["NED", "ENU", "NWU"])
def test_convert_earth_frame_rotates_into_the_other_components(frame: str, rng: np.random.Generator) -> None:
    """Body vectors rotated into NED then re-expressed == rotated with the converted attitude."""
    q_ned = qm.random_unit(100, rng)
    v_body = rng.normal(size=(100, 3))
    q_dst = convert_earth_frame(q_ned, "NED", frame)
    np.testing.assert_allclose(qm.rotate(q_dst, v_body), _ned_to(frame, qm.rotate(q_ned, v_body)), atol=1e-13)
    back = convert_earth_frame(q_dst, frame, "ned")  # names are case-insensitive
    np.testing.assert_allclose(qm.angle_between(back, q_ned), 0.0, atol=1e-7)


@pytest.mark.parametrize("src,dst", list(itertools.permutations(["NED", "ENU", "NWU"], 2)))
def test_conversions_compose(src: str, dst: str, rng: np.random.Generator) -> None:
    q = qm.random_unit(50, rng)
    direct = convert_earth_frame(q, src, dst)
    via_ned = convert_earth_frame(convert_earth_frame(q, src, "NED"), "NED", dst)
    np.testing.assert_allclose(qm.angle_between(direct, via_ned), 0.0, atol=1e-7)
    v = rng.normal(size=(50, 3))
    back = convert_earth_frame(direct, dst, src)
    np.testing.assert_allclose(qm.rotate(back, v), qm.rotate(q, v), atol=1e-13)


def test_broad_frame_example() -> None:
    """BROAD: an ENU attitude of identity (x east) is, in NED, a 90° yaw (x east)."""
    q = convert_earth_frame([1.0, 0, 0, 0], "ENU", "NED")
    np.testing.assert_allclose(qm.rotate(q, [1.0, 0, 0]), [0.0, 1.0, 0.0], atol=1e-15)  # east
    np.testing.assert_allclose(qm.rotate(q, [0.0, 0, 1.0]), [0.0, 0.0, -1.0], atol=1e-15)  # up


def test_unknown_frame_is_rejected() -> None:
    with pytest.raises(ValueError, match="NED, ENU or NWU"):
        convert_earth_frame([1.0, 0, 0, 0], "XYZ", "NED")


def test_24_axis_remaps_are_proper_and_distinct() -> None:
    assert len(AXIS_REMAPS) == 24
    mats = list(AXIS_REMAPS.values())
    for m in mats:
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=0)
        assert np.linalg.det(m) == pytest.approx(1.0)
        assert set(np.abs(m).ravel()) == {0.0, 1.0}
    keys = {tuple(m.astype(int).ravel()) for m in mats}
    assert len(keys) == 24
    np.testing.assert_array_equal(remap_matrix("+x+y+z"), np.eye(3))
    # the group is closed: every product of two remaps is a remap (the rotation group of the cube)
    for a in mats:
        for b in mats:
            assert tuple((a @ b).astype(int).ravel()) in keys


def test_remap_names_read_as_signed_sensor_axes() -> None:
    v = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(remap(v, "-x-y+z"), [-1.0, -2.0, 3.0])  # yaw 180°
    np.testing.assert_array_equal(remap(v, "+y-x+z"), [2.0, -1.0, 3.0])  # body x = sensor y
    np.testing.assert_array_equal(remap(np.tile(v, (4, 1)), "+x-y-z"), np.tile([1.0, -2.0, -3.0], (4, 1)))
    with pytest.raises(ValueError, match="unknown axis remap"):
        remap(v, "+x+x+z")
    with pytest.raises(ValueError):
        remap_matrix("+x+y-z")  # improper (a mirror): not one of the 24


def test_scalar_euler_to_q_matches_the_array_path() -> None:
    import numpy as np

    from mavahrs.geometry.rotation import euler_to_q_scalar, from_euler_rad

    rng = np.random.default_rng(3)
    for r, p, y in rng.uniform([-3.1, -1.5, -3.1], [3.1, 1.5, 3.1], size=(50, 3)):
        np.testing.assert_allclose(euler_to_q_scalar(r, p, y), from_euler_rad(r, p, y), atol=1e-12)
