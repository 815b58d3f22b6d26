r"""Settings from TOML files and command-line overrides, mapped onto the frozen settings dataclasses.

A configuration file has one table per settings object::

    [daemon]                     # mavahrs.service.daemon.DaemonSettings
    master = "udpin:0.0.0.0:14550"
    outputs = ["udpout:127.0.0.1:14551"]

    [pipeline]                   # mavahrs.service.pipeline.PipelineSettings
    filter_name = "madgwick"
    out_rate_hz = 50.0

    [filter.madgwick]            # the settings of one filter, by name
    max_gap_s = 1.0
    [filter.madgwick.schedule]   # a nested settings dataclass is a sub-table
    startup_s = 3.0

The mapping is generic (:func:`from_mapping`): any frozen dataclass, nested
dataclasses as sub-tables, tuples as arrays, ``X | None`` fields written as
the string ``"none"`` (or ``""`` for text fields) when they must be reset to
None.  An unknown key, a wrong type or a value the dataclass rejects raises
:class:`~mavahrs.errors.ConfigError` naming the key and the file.  Tables
``[filter.<name>]`` may be given for every filter; the one named by
``pipeline.filter_name`` is used.

Command-line values override the file: ``--out-rate 100`` and the generic
``--set pipeline.out_rate_hz=100`` / ``--set filter.beta_rad_s=0.05``
(``filter.KEY`` without a filter name means the filter in use).
:func:`dump_toml` writes the effective configuration back as TOML
(``mavahrs run --print-config``), :func:`example_toml` the commented example
in ``contrib/mavahrs.example.toml``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import sys
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mavahrs.errors import ConfigError

__all__ = [
    "RunConfig",
    "from_mapping",
    "to_mapping",
    "load_toml",
    "parse_override",
    "dump_toml",
    "field_docs",
    "load_run_config",
    "filter_settings_type",
    "default_filter_settings",
    "example_toml",
]

_NONE_WORDS = ("none",)


# --------------------------------------------------------------------------- TOML input


def load_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a TOML file.

    Raises:
        ConfigError: the file is missing, unreadable or not valid TOML (with line and column).
    """
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    p = os.fspath(path)
    try:
        with open(p, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file {p} not found") from None
    except OSError as exc:
        raise ConfigError(f"cannot read config file {p}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}{_none_hint(p, exc)}") from None
    except UnicodeDecodeError as exc:  # binary garbage: tomllib decodes UTF-8 before parsing
        raise ConfigError(f"config file {p} is not a text file (byte {exc.start} is not UTF-8)") from None


def _none_hint(path: str, exc: Exception) -> str:
    """The fix when the bad line is an example file's ``key = (none)`` uncommented as it stands."""
    line = getattr(exc, "lineno", None)
    if line is None:  # Python < 3.14: only in the message, "(at line N, column M)"
        m = re.search(r"at line (\d+)", str(exc))
        line = int(m.group(1)) if m else None
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read().splitlines()[line - 1] if line else ""
    except (OSError, UnicodeDecodeError, IndexError):
        return ""
    if re.search(r"=\s*\(none\)", text):
        return ' ("(none)" marks an unset setting in the example file: write "none" to leave it unset, or a value)'
    return ""


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"pipeline.out_rate_hz=100"`` → (["pipeline", "out_rate_hz"], 100).

    The value is read as a TOML value (numbers, true/false, "strings",
    [arrays]); anything that is not valid TOML is taken as a plain string.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*", key):
        raise ConfigError(f"--set {text!r}: expected SECTION.KEY=VALUE, e.g. pipeline.out_rate_hz=100")
    raw = raw.strip()
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key.split("."), value


# --------------------------------------------------------------------------- mapping


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _convert(tp: Any, value: Any, where: str, source: str, base: Any) -> Any:
    """``value`` (from TOML) as type ``tp``; ConfigError naming ``where`` and ``source`` if impossible."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    def bad(expected: str) -> ConfigError:
        return ConfigError(f"{source}: {where} must be {expected}, got {value!r}")

    if origin in (typing.Union, types.UnionType):
        non_none = [a for a in args if a is not type(None)]
        if type(None) in args:
            if isinstance(value, str):
                is_text = any(a is str for a in non_none)
                if (is_text and value == "") or (not is_text and value.strip().lower() in _NONE_WORDS):
                    return None
        errors = []
        for a in non_none:
            try:
                return _convert(a, value, where, source, base)
            except ConfigError as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        raise bad(" or ".join(_type_name(a) for a in non_none) + (' or "none"' if type(None) in args else ""))
    if origin is typing.Literal:
        if value not in args:
            raise bad("one of " + ", ".join(repr(a) for a in args))
        return value
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, Mapping):
            raise bad(f"a table of {tp.__name__} settings")
        return from_mapping(tp, value, base=base if isinstance(base, tp) else None, where=where, source=source)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise bad("an array")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]", source, None) for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise bad(f"an array of {len(args)} values")
        if not args:
            return tuple(value)
        return tuple(_convert(a, v, f"{where}[{i}]", source, None) for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise bad("an array")
        return [_convert(args[0], v, f"{where}[{i}]", source, None) if args else v for i, v in enumerate(value)]
    if tp is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if tp is int:
        if isinstance(value, bool):
            raise bad("a whole number")
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if not isinstance(value, int):
            raise bad("a whole number")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if isinstance(tp, type) and issubclass(tp, __import__("enum").Enum):
        try:
            return tp[value] if isinstance(value, str) and value in tp.__members__ else tp(value)
        except ValueError:
            raise bad("one of " + ", ".join(tp.__members__)) from None
    return value  # a type this mapper does not know: passed through, the dataclass validates


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001 - unresolved forward references: fall back to the raw annotations
        return {f.name: f.type for f in dataclasses.fields(cls)}


def from_mapping(
    cls: type,
    table: Mapping[str, Any],
    *,
    base: Any = None,
    where: str = "",
    source: str = "configuration",
) -> Any:
    """Build a ``cls`` (a dataclass) from a TOML table, starting from ``base`` (default: ``cls()``).

    Keys not given keep ``base``'s values; nested dataclass fields take
    sub-tables (merged into ``base``'s nested value).

    Raises:
        ConfigError: unknown key (named, with the keys that exist), wrong
            type, or a value ``cls`` rejects.
    """
    if base is None:
        try:
            base = cls()
        except Exception as exc:  # noqa: BLE001 - a settings class that needs arguments
            raise ConfigError(f"{source}: {where or cls.__name__} cannot be built without values: {exc}") from None
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = _hints(cls)
    changes: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{where}.{key}" if where else key
        if key not in fields:
            raise ConfigError(
                f"{source}: unknown setting {name!r} (known in [{where or cls.__name__}]: {', '.join(fields)})"
            )
        changes[key] = _convert(hints.get(key, Any), value, name, source, getattr(base, key, None))
    if not changes:
        return base
    try:
        return dataclasses.replace(base, **changes)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{source}: [{where or cls.__name__}] {exc}") from None


def to_mapping(obj: Any) -> dict[str, Any]:
    """A settings dataclass as a TOML-ready dict (None values left out, nested dataclasses as tables)."""
    out: dict[str, Any] = {}
    hints: dict[str, Any] | None = None
    for f in dataclasses.fields(obj):
        if not f.init:
            continue
        value = getattr(obj, f.name)
        if value is None:
            if f.default is None or f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                continue  # None is the default: nothing to write
            hints = hints if hints is not None else _hints(type(obj))
            text_field = str in typing.get_args(hints.get(f.name))
            out[f.name] = "" if text_field else "none"  # an explicit reset (see _convert)
            continue
        out[f.name] = to_mapping(value) if dataclasses.is_dataclass(value) else _plain(value)
    return out


def _plain(value: Any) -> Any:
    import enum

    if isinstance(value, enum.Enum):
        return value.name
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


# --------------------------------------------------------------------------- TOML output


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return _toml_value(str(value))


def dump_toml(sections: Mapping[str, Any], *, header: str = "") -> str:
    """Write nested dicts (or settings dataclasses) as TOML tables."""
    lines: list[str] = [f"# {line}" if line else "#" for line in header.splitlines()]

    def table(path: str, data: Mapping[str, Any]) -> None:
        scalars = {k: v for k, v in data.items() if not isinstance(v, Mapping)}
        tables = {k: v for k, v in data.items() if isinstance(v, Mapping)}
        if scalars or not tables:
            if lines:
                lines.append("")
            lines.append(f"[{path}]")
            for k, v in scalars.items():
                lines.append(f"{k} = {_toml_value(v)}")
        for k, v in tables.items():
            table(f"{path}.{k}", v)

    for name, data in sections.items():
        if dataclasses.is_dataclass(data):
            data = to_mapping(data)
        table(name, data)
    return "\n".join(lines) + "\n"


def field_docs(cls: type) -> dict[str, str]:
    """Field descriptions from the class docstring's ``Attributes:`` section (one paragraph each; an entry
    that names several fields, ``a, b: …``, describes each of them)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        doc = klass.__doc__ or ""
        m = re.search(r"^\s*Attributes:\s*$", doc, re.MULTILINE)
        if not m:
            continue
        current: list[str] = []
        indent = None
        for line in doc[m.end() :].splitlines():
            if not line.strip():
                continue
            ind = len(line) - len(line.lstrip())
            fm = re.match(r"^\s*([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s*(\([^)]*\))?:\s*(.*)$", line)
            if fm and (indent is None or ind <= indent):
                indent = ind
                current = [name.strip() for name in fm.group(1).split(",")]
                for name in current:
                    docs[name] = fm.group(3).strip()
            elif current and indent is not None and ind > indent:
                for name in current:
                    docs[name] = (docs[name] + " " + line.strip()).strip()
            elif indent is not None and ind < indent:
                break
    return docs


# --------------------------------------------------------------------------- the run configuration


@dataclass(frozen=True)
class RunConfig:
    """Everything ``mavahrs run`` needs.

    Attributes:
        daemon: links, recording, reporting (``[daemon]``).
        pipeline: scaling, timing, stream requests, output (``[pipeline]``).
        filter: the settings of the filter named by ``pipeline.filter_name``,
            or None for that filter's own defaults.
        sources: the files read, in order.
    """

    daemon: Any
    pipeline: Any
    filter: Any = None
    sources: tuple[str, ...] = ()

    def to_toml(self) -> str:
        sections: dict[str, Any] = {"daemon": self.daemon, "pipeline": self.pipeline}
        name = getattr(self.pipeline, "filter_name", "best")
        filt = self.filter if self.filter is not None else default_filter_settings(name)
        if filt is not None:
            sections["filter"] = {name: to_mapping(filt)}
        header = "mavahrs effective configuration" + (f" (from {', '.join(self.sources)})" if self.sources else "")
        return dump_toml(sections, header=header)


def default_filter_settings(name: str) -> Any:
    """The settings a filter uses when none are given (``"best"``: the project's tuned ones)."""
    from mavahrs.filters import create

    try:
        return create(name).settings
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def filter_settings_type(name: str) -> type:
    """The settings dataclass of filter ``name`` (``"best"`` included)."""
    return type(default_filter_settings(name))


def _filter_names() -> tuple[str, ...]:
    from mavahrs.filters import ALIASES, NAMES

    return tuple(NAMES) + tuple(ALIASES)


def _split_filter_tables(table: Any, source: str) -> dict[str, Mapping[str, Any]]:
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}: [filter] must be a table of [filter.<name>] tables")
    names = _filter_names()
    out: dict[str, Mapping[str, Any]] = {}
    for key, value in table.items():
        if key not in names:
            raise ConfigError(
                f"{source}: unknown filter table 'filter.{key}' (filters: {', '.join(names)}); "
                "filter settings go in [filter.<name>]"
            )
        if not isinstance(value, Mapping):
            raise ConfigError(f"{source}: filter.{key} must be a table")
        out[key] = value
    return out


def _nest(path: list[str], value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {path[-1]: value}
    for key in reversed(path[:-1]):
        out = {key: out}
    return out


def _merge(into: dict[str, Any], more: Mapping[str, Any]) -> None:
    for k, v in more.items():
        if isinstance(v, Mapping) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        else:
            into[k] = dict(v) if isinstance(v, Mapping) else v


def load_run_config(
    path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    daemon_type: type | None = None,
    pipeline_type: type | None = None,
) -> RunConfig:
    """Build the :class:`RunConfig` from optional TOML files and dotted overrides.

    Args:
        path: TOML file (``--config``), a sequence of them (``--config A --config B``: layered in
            order, a later file's settings over an earlier one's, table by table and key by key),
            or None for defaults.
        overrides: ``{"pipeline.out_rate_hz": 100, "daemon.outputs": [...], "filter.KEY": v}``
            from command-line flags; they win over the files.

    Raises:
        ConfigError: unreadable file, unknown keys, bad values (file or flag named).
    """
    if daemon_type is None:
        from mavahrs.service.daemon import DaemonSettings as daemon_type
    if pipeline_type is None:
        from mavahrs.service.pipeline import PipelineSettings as pipeline_type
    if path is None:
        paths: list[str] = []
    elif isinstance(path, (str, os.PathLike)):
        paths = [os.fspath(path)]
    else:
        paths = [os.fspath(x) for x in path]
    files: list[tuple[str, dict[str, Any]]] = []  # (source, data) in order
    for p in paths:
        data = load_toml(p)
        file_source = f"config file {p}"
        for key in data:
            if key not in ("daemon", "pipeline", "filter"):
                raise ConfigError(f"{file_source}: unknown table [{key}] (tables: [daemon], [pipeline], [filter.<name>])")
        files.append((file_source, data))
    cli: dict[str, Any] = {}
    for dotted, value in (overrides or {}).items():
        parts = dotted.split(".")
        if parts[0] not in ("daemon", "pipeline", "filter") or len(parts) < 2:
            raise ConfigError(f"command line: unknown setting {dotted!r} (use daemon.KEY, pipeline.KEY or filter.KEY)")
        _merge(cli, _nest(parts, value))

    layers = [*files, ("command line", cli)]
    daemon = pipeline = None
    for source, data in layers:
        table = cli.get("daemon", {}) if data is cli else _table(data, "daemon", source)
        daemon = from_mapping(daemon_type, table, base=daemon, where="daemon", source=source)
    for source, data in layers:
        table = cli.get("pipeline", {}) if data is cli else _table(data, "pipeline", source)
        pipeline = from_mapping(pipeline_type, table, base=pipeline, where="pipeline", source=source)
    name = getattr(pipeline, "filter_name", "best")
    file_filters = [(source, _split_filter_tables(data.get("filter", {}), source)) for source, data in files]
    cli_filter = dict(cli.get("filter", {}))
    names = _filter_names()
    cli_filters = {k: cli_filter.pop(k) for k in list(cli_filter) if k in names and isinstance(cli_filter[k], Mapping)}
    if cli_filter:  # filter.KEY: the filter in use
        _merge(cli_filters.setdefault(name, {}), cli_filter)
    filter_layers = [*file_filters, ("command line", cli_filters)]
    filt = None
    for fname in sorted({f for _, tables in filter_layers for f in tables} | {name}):
        if not any(fname in tables for _, tables in filter_layers):
            continue
        ftype = filter_settings_type(fname)
        settings = default_filter_settings(fname)
        for source, tables in filter_layers:
            settings = from_mapping(ftype, tables.get(fname, {}), base=settings, where=f"filter.{fname}", source=source)
        if fname == name:
            filt = settings
    return RunConfig(daemon=daemon, pipeline=pipeline, filter=filt, sources=tuple(paths))


def _table(data: Mapping[str, Any], key: str, source: str) -> Mapping[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        raise ConfigError(f"{source}: {key} must be a table ([{key}])")
    return value


# --------------------------------------------------------------------------- the example file


def _commented_table(path: str, cls: type, obj: Any, lines: list[str]) -> None:
    docs = field_docs(cls)
    hints = _hints(cls)
    lines.append("")
    lines.append(f"[{path}]")
    nested: list[tuple[str, type, Any]] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f.name, type(value), value))
            continue
        doc = docs.get(f.name, "")
        for line in _wrap(doc or f"({_type_name(hints.get(f.name, f.type))})", 96):
            lines.append(f"# {line}")
        shown = "(none)" if value is None else _toml_value(_plain(value))
        lines.append(f"#{f.name} = {shown}")
    for name, ncls, nobj in nested:
        doc = docs.get(name, "")
        if doc:
            lines.append("")
            for line in _wrap(doc, 96):
                lines.append(f"# {line}")
        _commented_table(f"{path}.{name}", ncls, nobj, lines)


def _wrap(text: str, width: int) -> list[str]:
    import textwrap

    text = re.sub(r":(?:class|func|meth|mod|attr|data):`~?([^`]+)`", r"`\1`", text).replace("``", "`")
    return textwrap.wrap(text, width) or [""]


def example_toml() -> str:
    """The commented example configuration: every setting, its meaning, unit and default."""
    from mavahrs.filters import NAMES
    from mavahrs.service.daemon import DaemonSettings
    from mavahrs.service.pipeline import PipelineSettings

    lines = [
        "# mavahrs example configuration (mavahrs run --config FILE).",
        "#",
        "# Every setting is shown commented out (\"#key = default\") below its description (\"# ...\");",
        "# uncomment what you change.",
        "# Command-line flags override this file; `mavahrs run --print-config` prints the result.",
        '# Optional settings shown as "(none)" are unset; write "none" (or "" for text) to unset one.',
        "# Generated by mavahrs.config.example_toml(); tests check it lists every setting.",
    ]
    _commented_table("daemon", DaemonSettings, DaemonSettings(), lines)
    _commented_table("pipeline", PipelineSettings, PipelineSettings(), lines)
    lines.append("")
    lines.append("# Filter settings, one table per filter; the one named by pipeline.filter_name is used.")
    for name in (*NAMES, "best"):
        settings = default_filter_settings(name)
        if name == "best":
            lines.append("")
            lines.append("# \"best\" is the project's recommended configuration; this table adjusts it.")
        _commented_table(f"filter.{name}", type(settings), settings, lines)
    return "\n".join(lines) + "\n"
