"""Rig files: a lab's own rig, written as the parameters in which it differs from the paper's.

A rig file is TOML. Its tables are the parts of :class:`~microg_env.params.RigParams`
(``[lander]``, ``[pad]``, ``[servo]``, ...) and their keys the parts' fields, so
``lander.mass_kg = 150.0`` and ``[lander]`` ``mass_kg = 150.0`` say the same. A value is a number
or a string, or ``{ value = 150.0, source = "weighed, 2026-03-02" }`` with where it comes from.
A top-level ``description`` says which rig it is. Every parameter not given is the paper's
(``RigParams()``); docs/model.md lists them with units and sources. :func:`load_rig` gives the
rig, :func:`read_rig` also the overrides and their sources.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from microg_env.files import read_toml, write_text
from microg_env.params import RigParams, parameter_paths, typed_overrides, with_overrides
from microg_env.validate import shown

#: The keys of a value given with its source.
NOTED_VALUE_KEYS = ("value", "source")


@dataclass(frozen=True)
class RigFile:
    """A rig file as read: its ``overrides`` by dotted path, the ``sources`` of those given one,
    and its ``description``."""

    overrides: dict[str, object]
    sources: dict[str, str] = field(default_factory=dict)
    description: str = ""

    @property
    def params(self) -> RigParams:
        return with_overrides(RigParams(), self.overrides)


def read_rig(path: str | Path) -> RigFile:
    """The rig file at ``path``; a one-line ValueError naming the file and the bad entry otherwise."""
    where = f"rig file {shown(str(path))}"
    data = read_toml(path, "rig file")
    description = data.pop("description", "")
    if not isinstance(description, str):
        raise ValueError(f"{where}: description must be a string, got {shown(description)}")
    values, sources = _flattened(data, where)
    try:
        overrides = typed_overrides(where, values)
        with_overrides(RigParams(), overrides)  # each part's own checks
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith(where) else f"{where}: {message}") from None
    return RigFile(overrides, sources, description)


def rig_file_text(rig: RigFile) -> str:
    """``rig`` as a rig file's text: its description, then a table per part, each value with its source."""
    lines = [f"description = {_toml_value(rig.description)}"] if rig.description else []
    parts: dict[str, list[str]] = {}
    for path in sorted(rig.overrides):
        part, _, name = path.rpartition(".")
        value = _toml_value(rig.overrides[path])
        if path in rig.sources:
            value = f"{{ value = {value}, source = {_toml_value(rig.sources[path])} }}"
        parts.setdefault(part, []).append(f"{name or part} = {value}")
    lines += parts.pop("", [])  # gravity_m_s2, at the top
    for part, entries in parts.items():
        lines += ["", f"[{part}]", *entries]
    return "\n".join(lines) + "\n"


def write_rig(rig: RigFile, path: str | Path) -> None:
    """Write ``rig`` as a rig file at ``path``, atomically; it reads back as ``rig``."""
    write_text(path, rig_file_text(rig))


def _toml_value(value: object) -> str:
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a TOML basic string (control characters escaped)
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)


def read_rig_option(path: str | Path, option: str) -> RigFile:
    """:func:`read_rig`, its error prefixed with the ``option`` that named the file (``--rig``)."""
    try:
        return read_rig(path)
    except ValueError as error:
        raise ValueError(f"{option}: {error}") from None


def load_rig(path: str | Path) -> RigParams:
    """The rig a rig file describes: ``gym.make("microg_env:MicroGravityLanding-v1", params=load_rig(path))``."""
    return read_rig(path).params


def _flattened(data: Mapping[str, object], where: str) -> tuple[dict[str, object], dict[str, str]]:
    """The file's values by dotted path, and the sources given with them."""
    parts = {path.partition(".")[0] for path in parameter_paths() if "." in path}
    values: dict[str, object] = {}
    sources: dict[str, str] = {}

    def put(path: str, entry: object) -> None:
        if isinstance(entry, Mapping):
            unknown = sorted(set(entry) - set(NOTED_VALUE_KEYS))
            if unknown or "value" not in entry:
                raise ValueError(
                    f'{where}: {path} must be a value or {{ value = ..., source = "..." }}, got the keys '
                    f"{', '.join(map(repr, entry))}"
                )
            source = entry.get("source", "")
            if not isinstance(source, str):
                raise ValueError(f"{where}: {path}.source must be a string, got {shown(source)}")
            if source:
                sources[path] = source
            entry = entry["value"]
        values[path] = entry

    for name, entry in data.items():
        if name in parts and isinstance(entry, Mapping):
            for key, value in entry.items():
                put(f"{name}.{key}", value)
        elif isinstance(entry, Mapping) and "value" not in entry:
            raise ValueError(f"{where}: unknown part {shown(name)}; the parts: {', '.join(sorted(parts))}")
        else:
            put(name, entry)
    return values, sources
