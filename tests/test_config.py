"""TOML configuration: generic dataclass mapping, file + command-line layering, errors, the example file."""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from mavahrs.config import (
    RunConfig,
    default_filter_settings,
    dump_toml,
    example_toml,
    field_docs,
    from_mapping,
    load_run_config,
    load_toml,
    parse_override,
    to_mapping,
)
from mavahrs.errors import ConfigError
from mavahrs.service.daemon import DaemonSettings

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Inner:
    """Inner.

    Attributes:
        tau_s: a time constant, s.
        on: a switch.
    """

    tau_s: float = 1.0
    on: bool = True

    def __post_init__(self) -> None:
        if self.tau_s <= 0:
            raise ValueError(f"tau_s must be positive, got {self.tau_s}")


@dataclass(frozen=True)
class Outer:
    """Outer.

    Attributes:
        rate_hz: a rate, Hz,
            continued on a second line.
        count: how many.
        name: a name.
        mode: one of a few words.
        ids: a tuple of ids.
        limit: optional limit; None = none.
        path: optional text.
        inner: nested settings.
    """

    rate_hz: float = 50.0
    count: int = 3
    name: str = "x"
    mode: Literal["a", "b"] = "a"
    ids: tuple[int, ...] = (1, 2)
    limit: int | None = 5
    path: str | None = None
    inner: Inner = field(default_factory=Inner)


def test_from_mapping_converts_types_and_merges_nested_tables() -> None:
    o = from_mapping(Outer, {"rate_hz": 100, "ids": [7, 8, 9], "mode": "b", "inner": {"on": False}})
    assert o.rate_hz == 100.0 and isinstance(o.rate_hz, float)
    assert o.ids == (7, 8, 9) and o.mode == "b"
    assert o.inner == Inner(tau_s=1.0, on=False)  # the nested default kept what was not given
    assert from_mapping(Outer, {"limit": "none", "path": ""}).limit is None
    assert from_mapping(Outer, {"path": "log.tlog"}).path == "log.tlog"
    assert from_mapping(Outer, {"count": 4.0}).count == 4
    base = Outer(count=9)
    assert from_mapping(Outer, {"name": "y"}, base=base) == Outer(count=9, name="y")


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        ({"rate": 1}, "unknown setting 'outer.rate' (known in [outer]: rate_hz, count"),
        ({"inner": {"tau": 1}}, "unknown setting 'outer.inner.tau'"),
        ({"count": True}, "outer.count must be a whole number, got True"),
        ({"count": 2.5}, "outer.count must be a whole number"),
        ({"rate_hz": "fast"}, "outer.rate_hz must be a number"),
        ({"on": 1}, "unknown setting"),
        ({"inner": {"on": "yes"}}, "outer.inner.on must be true or false"),
        ({"mode": "c"}, "outer.mode must be one of 'a', 'b'"),
        ({"ids": 3}, "outer.ids must be an array"),
        ({"limit": "lots"}, 'outer.limit must be'),
        ({"inner": {"tau_s": -1}}, "tau_s must be positive"),
        ({"inner": 3}, "a table of Inner settings"),
    ],
)
def test_from_mapping_errors_name_the_key_and_the_source(table: dict, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        from_mapping(Outer, table, where="outer", source="config file x.toml")
    msg = str(info.value)
    assert msg.startswith("config file x.toml: ") and needle in msg and "\n" not in msg


def test_field_docs_read_the_attributes_section() -> None:
    docs = field_docs(Outer)
    assert docs["rate_hz"] == "a rate, Hz, continued on a second line."
    assert docs["inner"] == "nested settings."
    assert set(docs) == {f.name for f in dataclasses.fields(Outer)}


def test_field_docs_give_an_entry_naming_several_fields_to_each_of_them() -> None:
    @dataclasses.dataclass
    class Pair:
        """Two limits.

        Attributes:
            first: the first, s.
            low_deg, high_deg: the band's
                edges, deg.
            last: the last.
        """

        first: float = 1.0
        low_deg: float = 0.0
        high_deg: float = 1.0
        last: float = 2.0

    docs = field_docs(Pair)
    assert docs["low_deg"] == docs["high_deg"] == "the band's edges, deg."
    assert docs["first"] == "the first, s." and docs["last"] == "the last."


def test_dump_toml_round_trips() -> None:
    o = Outer(rate_hz=math.inf, name='quote " and \\ backslash', limit=None, ids=(), inner=Inner(2.5, False))
    text = dump_toml({"outer": o})
    back = from_mapping(Outer, tomllib.loads(text)["outer"])
    assert back == o  # limit=None (default 5) is written as an explicit "none"
    assert to_mapping(Outer())["inner"] == {"tau_s": 1.0, "on": True}


@pytest.mark.parametrize(
    ("text", "path", "value"),
    [
        ("pipeline.out_rate_hz=100", ["pipeline", "out_rate_hz"], 100),
        ("daemon.outputs=['udpout:1.2.3.4:5']", ["daemon", "outputs"], ["udpout:1.2.3.4:5"]),
        ("daemon.master=udpin:0.0.0.0:14550", ["daemon", "master"], "udpin:0.0.0.0:14550"),
        ("pipeline.send_attitude_euler = true", ["pipeline", "send_attitude_euler"], True),
        ("filter.schedule.startup_s=2.5", ["filter", "schedule", "startup_s"], 2.5),
    ],
)
def test_parse_override(text: str, path: list[str], value: object) -> None:
    assert parse_override(text) == (path, value)


@pytest.mark.parametrize("text", ["out_rate_hz", "=3", "a..b=1", "pipeline.out-rate=1"])
def test_parse_override_rejects_non_assignments(text: str) -> None:
    with pytest.raises(ConfigError, match="SECTION.KEY=VALUE"):
        parse_override(text)


CONFIG = """
[daemon]
master = "udpin:0.0.0.0:14550"
outputs = ["udpout:127.0.0.1:14551", "tcpin:0.0.0.0:5761"]
status_interval_s = 2

[pipeline]
filter_name = "mahony"
out_rate_hz = 100

[filter.mahony]
kp_accel = 0.3
[filter.mahony.schedule]
startup_s = 1.5

[filter.madgwick]
max_gap_s = 0.5
"""


def test_file_then_command_line(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(CONFIG)
    cfg = load_run_config(path)
    assert cfg.daemon.outputs == ("udpout:127.0.0.1:14551", "tcpin:0.0.0.0:5761")
    assert cfg.daemon.status_interval_s == 2.0 and cfg.daemon.master == "udpin:0.0.0.0:14550"
    assert cfg.pipeline.filter_name == "mahony" and cfg.pipeline.out_rate_hz == 100.0
    assert cfg.filter.kp_accel == 0.3 and cfg.filter.schedule.startup_s == 1.5
    assert type(cfg.filter).__name__ == "MahonySettings"
    assert cfg.sources == (str(path),)

    cfg = load_run_config(
        path,
        {"pipeline.out_rate_hz": 0, "daemon.outputs": ["udpout:10.0.0.1:1"], "filter.ki_accel": 0.0,
         "filter.schedule.startup_s": 2.0},
    )
    assert cfg.pipeline.out_rate_hz == 0.0 and cfg.daemon.outputs == ("udpout:10.0.0.1:1",)
    assert cfg.filter.kp_accel == 0.3 and cfg.filter.ki_accel == 0.0  # filter.KEY = the filter in use
    assert cfg.filter.schedule.startup_s == 2.0

    cfg = load_run_config(path, {"pipeline.filter_name": "madgwick"})  # the other table applies
    assert type(cfg.filter).__name__ == "MadgwickSettings" and cfg.filter.max_gap_s == 0.5


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[daemon]\nmaster_url = 'x'\n", "unknown setting 'daemon.master_url'"),
        ("[pipeline]\nout_rate = 3\n", "unknown setting 'pipeline.out_rate'"),
        ("[filters]\n", "unknown table [filters]"),
        ("[filter.kalman]\n", "unknown filter table 'filter.kalman'"),
        ("[filter]\nbeta = 1\n", "unknown filter table 'filter.beta'"),
        ("[filter.mahony]\nkp = 1\n", "unknown setting 'filter.mahony.kp'"),
        ("[filter.mahony.schedule]\nstartup = 1\n", "unknown setting 'filter.mahony.schedule.startup'"),
        ("[daemon]\ntick_hz = 0\n", "daemon.tick_hz must be a positive number"),
        ("[pipeline]\nfilter_name = 'kalman'\n", "unknown filter 'kalman'"),
        ("[daemon\n", "is not valid TOML"),
    ],
)
def test_config_file_errors_name_file_and_key(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    msg = str(info.value)
    assert str(path) in msg and needle in msg, msg


def test_the_example_file_s_none_uncommented_as_it_stands_says_what_to_write(tmp_path: Path) -> None:
    """contrib/mavahrs.example.toml shows unset settings as ``#key = (none)``: uncommented as they stand,
    the TOML error says what "(none)" means and what to write; "none" then loads as documented."""
    from mavahrs.config import example_toml

    lines = example_toml().splitlines()
    k = lines.index("#duration_s = (none)")
    path = tmp_path / "mine.toml"
    path.write_text("\n".join(lines[:k] + ["duration_s = (none)"] + lines[k + 1 :]) + "\n")
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    msg = str(info.value)
    assert f"at line {k + 1}" in msg and 'write "none" to leave it unset' in msg, msg
    path.write_text("\n".join(lines[:k] + ['duration_s = "none"', "status_interval_s = 2"] + lines[k + 1 :]) + "\n")
    cfg = load_run_config(path)
    assert cfg.daemon.duration_s is None and cfg.daemon.status_interval_s == 2.0
    path.write_text("[daemon]\nstatus_interval_s = (2)\n")  # any other bad value: no such hint
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    assert "is not valid TOML" in str(info.value) and "(none)" not in str(info.value)


def test_command_line_errors_say_command_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="^command line: unknown setting 'daemon.nope'"):
        load_run_config(None, {"daemon.nope": 1})
    with pytest.raises(ConfigError, match="^command line: unknown setting 'general.x'"):
        load_run_config(None, {"general.x": 1})
    with pytest.raises(ConfigError, match="config file .* not found"):
        load_run_config(tmp_path / "missing.toml")


def test_effective_config_round_trips_through_toml(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(CONFIG)
    cfg = load_run_config(path, {"daemon.log_path": "x.tlog", "pipeline.system_id": 42})
    text = cfg.to_toml()
    assert text.startswith(f"# mavahrs effective configuration (from {path})")
    again = tmp_path / "again.toml"
    again.write_text(text)
    back = load_run_config(again)
    assert (back.daemon, back.pipeline, back.filter) == (cfg.daemon, cfg.pipeline, cfg.filter)


def _uncomment_settings(text: str) -> str:
    """Turn every ``#key = value`` line of the example into a setting (descriptions stay comments)."""
    out = []
    for line in text.splitlines():
        m = re.match(r"^#([A-Za-z_][A-Za-z0-9_]*) = (.*)$", line)
        if m and m.group(2) != "(none)":
            line = f"{m.group(1)} = {m.group(2)}"
        out.append(line)
    return "\n".join(out)


def test_example_file_is_current_and_lists_every_setting(tmp_path: Path) -> None:
    example = REPO / "contrib" / "mavahrs.example.toml"
    text = example_toml()
    assert example.read_text(encoding="utf-8") == text, (
        "contrib/mavahrs.example.toml is out of date: regenerate it with "
        "python3 -c 'from mavahrs.config import example_toml; print(example_toml(), end=\"\")' "
        "> contrib/mavahrs.example.toml"
    )
    data = tomllib.loads(_uncomment_settings(text))
    cfg = load_run_config(None)

    def assert_all_fields(table: dict, obj: object, where: str) -> None:
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                assert_all_fields(table[f.name], value, f"{where}.{f.name}")
            elif value is None:
                assert f"#{f.name} = (none)" in text
            else:
                assert f.name in table, f"{where}.{f.name} missing from the example"

    assert_all_fields(data["daemon"], cfg.daemon, "daemon")
    assert_all_fields(data["pipeline"], cfg.pipeline, "pipeline")
    # every setting uncommented at its documented default gives exactly the defaults
    uncommented = tmp_path / "all.toml"
    uncommented.write_text(_uncomment_settings(text))
    for name in data["filter"]:
        full = load_run_config(uncommented, {"pipeline.filter_name": name})
        plain = load_run_config(None, {"pipeline.filter_name": name})
        assert plain.filter is None  # no table: the pipeline builds the filter's defaults …
        assert full.filter == default_filter_settings(name), name  # … which the example states
        assert full.daemon == plain.daemon and full.pipeline == plain.pipeline


def test_every_daemon_setting_is_documented() -> None:
    docs = field_docs(DaemonSettings)
    assert set(docs) == {f.name for f in dataclasses.fields(DaemonSettings)}
    assert all(docs.values())


def test_load_toml_reports_position(tmp_path: Path) -> None:
    p = tmp_path / "x.toml"
    p.write_text("a = 1\nb = \n")
    with pytest.raises(ConfigError, match=r"line 2"):
        load_toml(p)


def test_runconfig_without_filter_table_uses_the_filter_defaults() -> None:
    cfg = load_run_config(None, {"pipeline.filter_name": "mahony"})
    assert isinstance(cfg, RunConfig) and cfg.filter is None  # the pipeline builds the defaults
    assert "[filter.mahony]" in cfg.to_toml() and "[filter.mahony.schedule]" in cfg.to_toml()
