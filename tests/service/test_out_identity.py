"""``pipeline.out_identity`` (``mavahrs run --out-identity``) in the pipeline: the checks and the edge cases.

QGroundControl before 4.2 draws any component's ATTITUDE_QUATERNION of the vehicle's system on
its HUD (docs/ecosystem.md#qgroundcontrol). What goes over real sockets with each identity is
tested with the daemon in test_daemon_loop.py; here the setting's validation, a separate vehicle
that would take the autopilot's system id, and our own HEARTBEAT relayed back.
"""

from __future__ import annotations

from typing import Any

import pytest

from mavahrs.errors import ConfigError
from mavahrs.protocol.codec import MavCodec
from mavahrs.service.pipeline import Pipeline, PipelineSettings

FIXED_WING, ARDUPILOT, GENERIC = 1, 3, 0  # MAV_TYPE_FIXED_WING, MAV_AUTOPILOT_ARDUPILOTMEGA / GENERIC


def test_the_option_is_checked() -> None:
    with pytest.raises(ConfigError, match="^out_identity must be one of component, separate-vehicle, none, got 'qgc'$"):
        PipelineSettings(out_identity="qgc")


def _heartbeat(sysid: int, compid: int, mav_type: int, autopilot: int) -> Any:
    codec = MavCodec(sysid, compid)
    (msg,) = MavCodec().receive_datagram(codec.encode(codec.mav.heartbeat_encode(mav_type, autopilot, 0, 0, 4)))
    return msg


def test_a_separate_vehicle_never_uses_the_autopilots_system_id() -> None:
    p = Pipeline(PipelineSettings(filter_name="mahony", out_identity="separate-vehicle", system_id=1))
    assert p.handle(_heartbeat(1, 1, FIXED_WING, ARDUPILOT), 1_000_000) == []
    out = p.tick(1_100_000)
    assert out and all(not o.to_outputs and o.frame[7] == 76 for o in out)  # the stream requests (COMMAND_LONG) only
    warnings = [text for level, text in p.drain_notices() if level >= 30]
    assert warnings == [
        "out_identity separate-vehicle: system id 1 is the autopilot's own, so a ground station would take our "
        "attitude for the autopilot's; sending nothing (set pipeline.system_id, --sysid, to a free system id)"
    ]


def test_our_own_heartbeat_relayed_back_is_not_a_second_autopilot() -> None:
    p = Pipeline(PipelineSettings(filter_name="mahony", out_identity="separate-vehicle"))
    p.handle(_heartbeat(1, 1, FIXED_WING, ARDUPILOT), 1_000_000)
    (hb,) = [o for o in p.tick(1_100_000) if o.frame[7] == 0]  # msgid 0: our HEARTBEAT
    (echo,) = MavCodec().receive_datagram(hb.frame)
    assert (echo.get_srcSystem(), echo.get_srcComponent(), echo.autopilot) == (42, 1, GENERIC)
    p.handle(echo, 1_200_000)
    assert p.source == (1, 1)
    assert "other_autopilot_heartbeats" not in p.status(1_300_000).counters
    notices = [text for _, text in p.drain_notices()]
    assert "attitude sent as a separate vehicle: system 42, component 1 (the autopilot is system 1)" in notices
    assert not any("second autopilot" in text for text in notices)
