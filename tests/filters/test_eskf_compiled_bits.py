"""The compiled ESKF gives its interpreted source's floats bit for bit, on firmware_sim flights.

How numba compiles the ESKF's step — which helpers it inlines at its IR level (``@kernel(inline=True)``) and
which it leaves as calls (eight large ones since speed3: a cold compile of the step 145 → 63 CPU-s,
docs/reliability.md "Suite time, round three") — must not move the estimate.  Without ``fastmath`` every
compiled operation is the interpreted one, in the same order, so the batch loop, the daemon's per-sample kernel
and the pure-Python reference (:func:`mavahrs.filters.jit.pure_python`) agree in every output column of every
sample (quaternion, σ, flags, diagnostics), not only to the 1e-9 of tests/filters/test_contract.py.  The two
flights (aggressive with GNSS; hover without, where the rest-rate update runs) between them run each of the
helpers left as calls: checked on the interpreted run, so the comparison covers them.

(What the helpers' own compilation costs is not tested: a cold compile's CPU time depends on the machine and
its load; scripts/profile_compile.py measures it.)
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mavahrs.filters import create
from mavahrs.filters import eskf as eskf_module
from mavahrs.filters.jit import HAVE_NUMBA
from mavahrs.replay import ReplaySettings, replay
from mavahrs.sensors.profiles import get_profile

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed: nothing is compiled")

#: the ESKF's helpers compiled as calls of their own, not inlined into its step
CALLED_HELPERS = ("_drag_update", "_rest_rate_update", "_propagate_covariance", "_scalar_update",
                  "_heading_update", "_heading_walk_step", "_mag_noise_step", "_axis_start_check")  # fmt: skip

#: (scenario, seed, extra firmware_sim arguments, [(filter, the pipeline's setup or the plain API)])
FLIGHTS = [
    ("aggressive", "2", (), [("eskf", "vehicle"), ("best", "plain")]),
    ("hover", "3", ("--stream", "GLOBAL_POSITION_INT=0"), [("eskf", "plain"), ("best", "vehicle")]),
]


def _configured(name: str, mode: str, delay_s: float, compiled: bool) -> Any:
    """``name`` as the daemon's pipeline sets it up for an autopilot's multirotor (``vehicle``) or as created."""
    f = create(name, compiled=compiled)
    if mode == "vehicle":
        f.set_multirotor()
        f.set_sensor_delay(delay_s)
        if hasattr(f, "set_vehicle_stream"):
            f.set_vehicle_stream()
    return f


def _calls_of(codes: dict[Any, str], seen: set[str]) -> Callable[..., None]:
    def profile(frame: Any, event: str, arg: Any) -> None:
        if event == "call" and frame.f_code in codes:
            seen.add(codes[frame.f_code])

    return profile


def test_compiled_eskf_equals_its_interpreted_source_bit_for_bit(
    tmp_path: Path, sim_tlog_writer: Callable[..., Path]
) -> None:
    codes = {getattr(eskf_module, n).py_func.__code__: n for n in CALLED_HELPERS}
    for n in CALLED_HELPERS:  # a plain kernel of its own: a dispatcher numba does not inline
        assert getattr(eskf_module, n).targetoptions.get("inline", "never") == "never", n
    seen: set[str] = set()
    for scenario, seed, extra, runs in FLIGHTS:
        log = sim_tlog_writer(tmp_path / f"{scenario}.tlog", "--scenario", scenario, "--duration", "20",
                              "--seed", seed, *extra)  # fmt: skip
        res = replay(log, ReplaySettings(filters=("complementary",)))  # the daemon's decoding and rows
        rows = res.inputs.rows
        scale = get_profile(res.inputs.profile).scale_for(res.inputs.message)
        delay = 0.0 if scale is None else scale.delay_s
        assert rows.shape[0] >= 4000
        for name, mode in runs:
            batch = _configured(name, mode, delay, compiled=True).run(rows)
            per_sample = _configured(name, mode, delay, compiled=True)
            one = np.array([per_sample.update_row(r).copy() for r in rows])
            reference = _configured(name, mode, delay, compiled=False)
            sys.setprofile(_calls_of(codes, seen))
            try:
                interpreted = reference.run(rows)
            finally:
                sys.setprofile(None)
            for label, got in (("batch", batch), ("per sample", one)):
                differ = np.argwhere(got.view(np.uint64) != interpreted.view(np.uint64))
                assert len(differ) == 0, (
                    f"{scenario} {name} ({mode}), {label}: {len(differ)} values differ from the interpreted "
                    f"kernel's, first at row/column {tuple(int(i) for i in differ[0])}"
                )
    assert seen == set(CALLED_HELPERS), f"not run on these flights: {sorted(set(CALLED_HELPERS) - seen)}"
