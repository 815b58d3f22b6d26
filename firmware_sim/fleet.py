"""A small simulated fleet: many short tlogs of mixed scenarios, some with an injected estimator fault.

For the fleet tests and ``scripts/bench_fleet.py``: :func:`mixed_fleet` says
what each log is (scenario, autopilot, rates, seed, fault), :func:`write_fleet_log`
writes one as ``mavahrs-sim --tlog … --fast`` would (the ``bench`` preset:
IMUs as fast as the autopilot allows, ATTITUDE at 50 Hz, GNSS, truth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from firmware_sim.endpoint import Endpoint, EndpointSettings
from firmware_sim.simulation import AttitudeFault, SimSettings, Simulation
from firmware_sim.streamer import write_tlog

__all__ = ["FleetLog", "mixed_fleet", "write_fleet_log", "FAULT"]

#: The injected fault: the autopilot's roll estimate drifts 15° off from 12 s (ramped over 1 s) to the end;
#: it passes 10° (the monitor's threshold) at 12.67 s, so the monitor's WARNING is due 2 s later.
FAULT = AttitudeFault(start_s=12.0, duration_s=math.inf, roll_deg=15.0, ramp_s=1.0)
#: Gentle enough for the autopilot's attitude and mavahrs's to agree within the monitor's thresholds.
CLEAN_SCENARIOS = ("rest", "hover", "magnetic", "temperature", "vibration", "aggressive")


@dataclass(frozen=True)
class FleetLog:
    """One simulated flight of the fleet.

    Attributes:
        name: file name (``.tlog``).
        scenario, seed, autopilot: as ``mavahrs-sim``.
        duration_s: simulated seconds.
        loop_rate_hz: the autopilot's loop (the IMU stream rate follows from it).
        imus: IMU count.
        sysid: MAVLink system id (a fleet: each airframe its own).
        fault: an estimator fault injected into the ATTITUDE stream, or None.
    """

    name: str
    scenario: str
    seed: int
    duration_s: float
    autopilot: str = "ardupilot"
    loop_rate_hz: float = 400.0
    imus: int = 2
    sysid: int = 1
    fault: AttitudeFault | None = None

    @property
    def fault_onset_s(self) -> float:
        """When the fault's offset passes 10° (the monitor's default tilt threshold), s of boot time."""
        f = self.fault
        if f is None:
            return math.nan
        return f.start_s + f.ramp_s * min(1.0, 10.0 / abs(f.roll_deg))


def mixed_fleet(n: int, *, faults: int = 2, clean_s: float = 12.0, fault_s: float = 20.0) -> list[FleetLog]:
    """``n`` flights cycling through the clean scenarios, autopilots, loop rates and IMU counts; the
    last ``faults`` of them fly ``hover`` for ``fault_s`` with :data:`FAULT` in their ATTITUDE."""
    out: list[FleetLog] = []
    for i in range(n - faults):
        out.append(FleetLog(
            name=f"flight_{i:03d}_{CLEAN_SCENARIOS[i % len(CLEAN_SCENARIOS)]}.tlog",
            scenario=CLEAN_SCENARIOS[i % len(CLEAN_SCENARIOS)], seed=100 + i, duration_s=clean_s,
            autopilot="px4" if i % 5 == 4 else "ardupilot", loop_rate_hz=(400.0, 200.0, 300.0)[i % 3],
            imus=1 + i % 2, sysid=1 + i % 7,
        ))  # fmt: skip
    for j in range(faults):
        i = n - faults + j
        out.append(FleetLog(name=f"flight_{i:03d}_hover_fault.tlog", scenario="hover", seed=100 + i,
                            duration_s=fault_s, sysid=1 + i % 7, fault=FAULT))  # fmt: skip
    return out


def fleet_sim_settings(log: FleetLog) -> SimSettings:
    """The simulator's settings for ``log``: compiled physics, and its autopilot's IMU front end
    (:meth:`SimSettings.for_autopilot`: a PX4 sends vehicle_imu's interval mean, as on the command line)."""
    return SimSettings(jit=True, scenario=log.scenario, seed=log.seed, loop_rate_hz=log.loop_rate_hz,
                       imu_count=log.imus, attitude_fault=log.fault).for_autopilot(log.autopilot)  # fmt: skip


def write_fleet_log(folder: str | Path, log: FleetLog) -> Path:
    """Simulate ``log`` into ``folder/log.name`` (compiled physics, as ``--fast``); returns the path."""
    sim = fleet_sim_settings(log)
    ep = EndpointSettings(autopilot=log.autopilot, system_id=log.sysid, preset="bench", block_ticks=2000)
    path = Path(folder) / log.name
    write_tlog(Endpoint(Simulation(sim), ep), path, log.duration_s)
    return path
