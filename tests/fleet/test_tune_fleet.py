"""``mavahrs tune LOG LOG …``: one set of gains over several flights, serially and on a local Dask cluster."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mavahrs.cli import main

pytestmark = pytest.mark.slow
for _module in ("distributed", "pyarrow"):
    pytest.importorskip(_module, reason="the fleet extra is not installed: pip install '.[fleet]'")


@pytest.fixture(scope="module")
def rests(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three simulated flights: two at rest, one hovering (its SIMSTATE true rates are subtracted)."""
    from firmware_sim.fleet import FleetLog, write_fleet_log

    folder = tmp_path_factory.mktemp("tune")
    logs = [FleetLog("rest_a.tlog", "rest", 1, 20.0), FleetLog("rest_b.tlog", "rest", 2, 30.0, loop_rate_hz=200.0),
            FleetLog("hover_c.tlog", "hover", 3, 20.0)]  # fmt: skip
    return [write_fleet_log(folder, log) for log in logs]


def _tune(capsys: pytest.CaptureFixture[str], *args: str) -> dict:  # type: ignore[type-arg]
    assert main(["tune", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_several_flights_give_one_set_of_gains(rests: list[Path], capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path) -> None:  # fmt: skip
    single = [_tune(capsys, str(p)) for p in rests]
    both = _tune(capsys, *map(str, rests))
    num = sum(s["beta_ls_terms"][0] for s in single)
    den = sum(s["beta_ls_terms"][1] for s in single)
    assert both["beta_ls"] == pytest.approx(num / den, rel=1e-12)
    assert min(s["beta_ls"] for s in single) < both["beta_ls"] < max(s["beta_ls"] for s in single)
    assert both["samples"] == sum(s["samples"] for s in single) and both["name"] == "3 recordings"
    assert both["notes"] == ["one set of gains over 3 recordings (rest_a, rest_b, hover_c): least-squares terms "
                             "summed, noise figures averaged by samples; no temperature model (the bias differs "
                             "per power-up)"]  # fmt: skip
    # the same on a local Dask cluster, one task per flight
    on_dask = _tune(capsys, *map(str, rests), "--dask", "--workers", "2")
    assert json.dumps(on_dask, sort_keys=True) == json.dumps(both, sort_keys=True)  # NaN fields too
    toml = tmp_path / "fleet.toml"
    assert main(["tune", *map(str, rests), "--gains", "ls", "-o", str(toml)]) == 0
    from mavahrs.config import load_run_config

    assert load_run_config(toml).filter.beta_rad_s == pytest.approx(both["beta_ls"], rel=1e-5)


def test_a_bad_recording_on_dask_is_one_line_without_worker_traceback(
    rests: list[Path], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A recording tune refuses, among good ones on a local cluster: the reason in one line, exit 1, no file,
    and no "Compute Failed … Traceback" from the worker processes (they write to the same terminal)."""
    from firmware_sim.fleet import FleetLog, write_fleet_log

    short = write_fleet_log(tmp_path, FleetLog("short.tlog", "rest", 4, 0.3))
    toml = tmp_path / "fleet.toml"
    assert main(["tune", *map(str, rests), str(short), "--dask", "--workers", "2", "--gains", "ls",
                 "-o", str(toml)]) == 1  # fmt: skip
    err = capfd.readouterr().err
    assert not toml.exists()
    assert "Traceback" not in err and "Compute Failed" not in err, err
    assert "short" in err and "usable samples" in err
