"""Layer direction: lower layers never import higher ones (architecture.md).

geometry → filters → sensors → protocol → transports → service → cli, with
evaluation beside the service layer (it may use the service's pipeline; the
service never imports evaluation), replay and demo above both.  ``mavahrs`` never imports
``firmware_sim``; the sans-I/O layers never touch sockets, files or clocks.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PKG = REPO / "mavahrs"

# Rank of each top-level subpackage/module; a module may import only from ranks ≤ its own.
RANK = {
    "errors": 0,
    "geometry": 1,
    "filters": 2,
    "api": 3,
    "sensors": 3,
    "protocol": 4,
    "transports": 5,
    "ingest": 5,
    "config": 6,
    "service": 6,
    "evaluation": 6,
    "logs": 6,
    "replay": 7,
    "demo": 7,
    "warmup": 7,
    "fleet": 7,
    "cli": 8,
    "__main__": 9,
    "__init__": 9,
}

#: imports forbidden between layers of the same rank: the daemon (service) never needs the
#: evaluation tools (metrics, plots, truth loaders); evaluation may use the service's pipeline.
FORBIDDEN_SIDEWAYS = {"service": {"evaluation"}}

SANS_IO = ("geometry", "filters", "sensors", "protocol", "ingest")
FORBIDDEN_IN_SANS_IO = {"socket", "selectors", "serial", "subprocess", "threading", "asyncio", "time"}


def _modules() -> list[Path]:
    return sorted(p for p in PKG.rglob("*.py"))


def _layer(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0].removesuffix(".py")


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
    return out


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(REPO)))
def test_layers_only_import_downwards(path: Path) -> None:
    layer = _layer(path)
    assert layer in RANK, f"{path}: new top-level module {layer!r} needs a rank in test_architecture.py"
    for name in _imports(path):
        assert not name.startswith("firmware_sim"), f"{path} imports {name}: mavahrs never imports firmware_sim"
        if not name.startswith("mavahrs."):
            continue
        target = name.split(".")[1]
        if target not in RANK:
            continue
        assert RANK[target] <= RANK[layer], f"{path} ({layer}) imports {name} ({target}): upward dependency"
        assert target not in FORBIDDEN_SIDEWAYS.get(layer, ()), (
            f"{path} ({layer}) imports {name} ({target}): {layer} must not depend on {target}"
        )


@pytest.mark.parametrize(
    "path",
    [p for p in _modules() if _layer(p) in SANS_IO],
    ids=lambda p: str(p.relative_to(REPO)),
)
def test_sans_io_layers_do_no_io(path: Path) -> None:
    for name in _imports(path):
        root = name.split(".")[0]
        assert root not in FORBIDDEN_IN_SANS_IO, f"{path} imports {name}: {_layer(path)} must stay free of I/O and clocks"


def test_firmware_sim_depends_only_on_lower_layers() -> None:
    sim = REPO / "firmware_sim"
    if not sim.exists():
        pytest.skip("firmware_sim not present")
    for path in sim.rglob("*.py"):
        for name in _imports(path):
            if name.startswith("mavahrs."):
                target = name.split(".")[1]
                assert target in {"geometry", "protocol", "transports", "errors", "filters"}, (
                    f"{path} imports {name}: the simulator may use geometry, protocol and transports only"
                )


# --------------------------------------------------------------------------- the layout users find their way by

#: the room for each job, from the folder names alone (README "Where each step lives")
LAYOUT = {
    "read a new log format": "mavahrs/logs",
    "change how gaps are handled (the sample chain over arrays)": "mavahrs/ingest",
    "replay a log through the filters": "mavahrs/replay",
    "score against a kind of truth": "mavahrs/evaluation",
    "a fleet's logs": "mavahrs/fleet",
}


def test_each_job_has_its_room() -> None:
    for job, room in LAYOUT.items():
        assert (REPO / room / "__init__.py").is_file(), f"{job}: expected the package {room}"
    assert not (PKG / "replay.py").exists(), "the replay engine lives in mavahrs/replay/, not a module beside it"
    assert (PKG / "replay" / "engine.py").is_file()


def test_every_log_reader_is_a_module_of_logs_with_one_entry_point() -> None:
    """``mavahrs.logs`` dispatches by content to one ``read_<format>`` per reader module; none of them reaches
    up into replay, fleet or the command line."""
    import mavahrs.logs as logs

    readers = {p.stem for p in (PKG / "logs").glob("*.py") if p.stem != "__init__"}
    assert readers == {"dataflash", "ulog"}
    assert set(logs.FORMATS) == {"tlog", "dataflash", "ulog"}
    for stem in readers:
        src = (PKG / "logs" / f"{stem}.py").read_text(encoding="utf-8")
        assert f"def read_{stem}(" in src, f"mavahrs/logs/{stem}.py: its entry point read_{stem}()"
        for name in _imports(PKG / "logs" / f"{stem}.py"):
            # nor into evaluation: the sample chain they share is mavahrs.ingest (evaluation reads the logs)
            assert not name.startswith(("mavahrs.replay", "mavahrs.fleet", "mavahrs.cli", "mavahrs.evaluation")), (
                stem,
                name,
            )


def test_evaluation_does_not_hold_or_import_the_replay_engine() -> None:
    for path in (PKG / "evaluation").rglob("*.py"):
        assert path.stem != "replay", path
        for name in _imports(path):
            assert not name.startswith("mavahrs.replay"), f"{path} imports {name}: evaluation reads replay's outputs"


# --------------------------------------------------------------------------- the one sample chain

#: each step of the sample chain: the module that defines it (once), as a compiled per-sample function,
#: and the loop over it beside it
SAMPLE_STEPS = {
    "scale_int_row": ("sensors/scaling.py", "scale_int_rows"),
    "scale_float_row": ("sensors/scaling.py", "scale_float_rows"),
    "blank_unusable": ("sensors/sample.py", "blank_unusable_rows"),
    "calibrate_row": ("sensors/calibration.py", "calibrate_rows"),
    "resend_row": ("ingest/resend.py", "resend_rows"),
    "timeline_step": ("ingest/timeline.py", "timeline_loop"),
    "select_step": ("sensors/imu_select.py", "select_loop"),
    "bias_restore_step": ("ingest/autopilot_bias.py", "bias_restore_rows"),
}
#: who runs the steps: the live pipeline (through Scaler / Calibrator / write_row), the daemon's fast
#: lane, and the readers (the loops)
STEP_USERS = {
    "service/fastlane.py": {"scale_int_row", "timeline_step"},
    "evaluation/tlogdata.py": {"scale_int_rows", "scale_float_rows", "blank_unusable_rows", "resend_rows",
                               "select_over_arrays", "bias_restore_rows"},
    "service/pipeline.py": {"ResendFilter", "Timeline", "ImuSelector", "AutopilotBias"},
    "ingest/arrays.py": {"scale_float_rows", "blank_unusable_rows", "timeline_loop", "select_loop"},
    "logs/dataflash.py": {"si_rows", "select_over_arrays"},
    "logs/ulog.py": {"si_rows", "select_over_arrays"},
}


def _defined(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}


def test_each_sample_step_is_defined_once_with_its_loop_beside_it() -> None:
    defs: dict[str, list[str]] = {}
    for path in _modules():
        for name in _defined(path):
            defs.setdefault(name, []).append(str(path.relative_to(PKG)))
    for step, (home, loop) in SAMPLE_STEPS.items():
        assert defs.get(step) == [home], f"{step}: defined in {defs.get(step)}, expected once in {home}"
        assert defs.get(loop) == [home], f"{loop} (the loop over {step}) belongs beside it in {home}"


def test_the_pipeline_the_fast_lane_and_every_reader_run_those_steps() -> None:
    for rel, names in STEP_USERS.items():
        src = (PKG / rel).read_text(encoding="utf-8")
        for name in names:
            assert f"{name}(" in src, f"mavahrs/{rel} no longer calls {name}: a second copy of the step?"
        # the scaling constants belong to the scaling step alone
        for const in ("scaling.saturation_fraction", "scaling.implausible_factor", ".mag_legacy_to_ut"):
            assert const not in src, f"mavahrs/{rel} uses {const}: the scaling step's own constant"
    scaling = (PKG / "sensors" / "scaling.py").read_text(encoding="utf-8")
    assert "scale_int_row(" in scaling.split("class Scaler", 1)[1] and "scale_float_row(" in scaling.split("class Scaler", 1)[1]
    assert "calibrate_row(" in (PKG / "sensors" / "calibration.py").read_text(encoding="utf-8").split("class Calibrator", 1)[1]
    assert "resend_row(" in (PKG / "ingest" / "resend.py").read_text(encoding="utf-8").split("class ResendFilter", 1)[1]
    timeline = (PKG / "ingest" / "timeline.py").read_text(encoding="utf-8")
    assert "timeline_step(" in timeline.split("class Timeline", 1)[1] and "timeline_step(" in timeline.split("def timeline_loop", 1)[1]
    assert not (PKG / "protocol" / "timeline.py").exists(), "the timeline is a step of the sample chain (mavahrs/ingest)"
    selector = (PKG / "sensors" / "imu_select.py").read_text(encoding="utf-8")
    assert "select_step(" in selector.split("class ImuSelector", 1)[1] and "select_step(" in selector.split("def select_loop", 1)[1]


def test_no_reader_re_implements_the_imu_selector_s_rules() -> None:
    """The health rules (all-zero, stale, frozen, saturated, disagreeing) live in the selector's step alone: the
    readers run its loop and keep no shortcut that judges an instance healthy by themselves."""
    for rel in ("evaluation/tlogdata.py", "logs/dataflash.py", "logs/ulog.py", "ingest/arrays.py", "replay/engine.py"):
        src = (PKG / rel).read_text(encoding="utf-8")
        for word in ("freeze_s", "stale_s", "freeze_min_samples", ".observe("):
            assert word not in src, f"mavahrs/{rel} uses {word}: the IMU selector's rule outside its step"
