"""firmware_sim: a simulated flight controller that streams MAVLink IMU data with known true attitude.

A sibling of :mod:`mavahrs` in the same distribution (``mavahrs`` never imports it).
Layers: :mod:`~firmware_sim.trajectory` (scenarios) → :mod:`~firmware_sim.vehicle`
(rigid-body truth) → :mod:`~firmware_sim.imu_model` (sensors) →
:mod:`~firmware_sim.simulation` (per loop tick) → :mod:`~firmware_sim.encoder`
(MAVLink frames via ``mavahrs.protocol.codec``) → :mod:`~firmware_sim.endpoint`
(the autopilot's MAVLink behaviour, sans I/O) → :mod:`~firmware_sim.streamer` (links, pacing, tlog).
Run it with ``python -m firmware_sim`` or ``mavahrs-sim``; see ``docs/firmware_sim.md``.
"""

from __future__ import annotations

from firmware_sim.endpoint import DENIED_TEXT, STREAMABLE, Endpoint, EndpointSettings
from firmware_sim.imu_model import EarthField, ImuErrorSettings, MagSettings
from firmware_sim.simulation import (
    AttitudeFault,
    CurrentSettings,
    Home,
    ImuFault,
    LoopBlock,
    MagAnomaly,
    SimSettings,
    Simulation,
)
from firmware_sim.trajectory import SCENARIO_DESCRIPTIONS, SCENARIOS
from firmware_sim.vehicle import VehicleSettings

__all__ = [
    "SCENARIOS",
    "SCENARIO_DESCRIPTIONS",
    "SimSettings",
    "Simulation",
    "LoopBlock",
    "Home",
    "AttitudeFault",
    "ImuFault",
    "MagAnomaly",
    "CurrentSettings",
    "VehicleSettings",
    "ImuErrorSettings",
    "MagSettings",
    "EarthField",
    "Endpoint",
    "EndpointSettings",
    "STREAMABLE",
    "DENIED_TEXT",
]
