"""The scenario file's reference, generated from the models that validate it (docs/scenarios.md).

Every key a scenario file may hold — its type and bounds as the pydantic models check them, its default, its
description (with its unit) — walked from :class:`cdpr.config.scenario.ScenarioSpec`, and an example of each
from the shipped scenarios where one sets it. ``cdpr scenarios --reference`` prints it; tests/test_reference.py
fails when docs/scenarios.md is not this text, so the page cannot drift from the loader.
"""

from __future__ import annotations

import json
import types
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, RootModel
from pydantic.fields import FieldInfo

from cdpr.config.loading import read_yaml, resolve, shipped_names


@dataclass(frozen=True)
class Row:
    key: str  # dotted; ``[]`` for the items of a list
    type: str
    default: str
    description: str
    section: bool  # a mapping of keys (rows follow)
    variant: tuple[str, str, str] | None = None  # a union's member: (its section's key, its tag key, its tag value)


def _bounds(meta: list[Any]) -> str:
    out = []
    for m in meta:
        for name, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            if getattr(m, name, None) is not None:
                out.append(f"{sign} {getattr(m, name):g}")
        if getattr(m, "min_length", None):  # pydantic's constraints (annotated-types' MinLen, MaxLen), by name
            out.append(f"at least {m.min_length}")
        if getattr(m, "max_length", None) is not None:
            out.append(f"at most {m.max_length}")
    return ", ".join(out)


def _models(ann: Any) -> list[tuple[type[BaseModel], bool]]:
    """The models inside an annotation, each with whether it is a list's item."""
    origin, args = get_origin(ann), get_args(ann)
    if isinstance(ann, type) and issubclass(ann, RootModel):
        return _models(ann.model_fields["root"].annotation)
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return [(ann, False)]
    if origin is Annotated:
        return _models(args[0])
    if origin is list:
        return [(m, True) for m, _ in _models(args[0])]
    if origin in (Union, types.UnionType):
        return [m for a in args for m in _models(a)]
    return []


def _length(meta: list[Any]) -> int | None:
    """The exact length a list must have (min_length = max_length), if any."""
    low = next((m.min_length for m in meta if getattr(m, "min_length", None) is not None), None)
    high = next((m.max_length for m in meta if getattr(m, "max_length", None) is not None), None)
    return low if low is not None and low == high else None


PLURALS = {"number": "numbers", "text": "texts", "integer": "integers"}


def _type(ann: Any, meta: list[Any] | None = None) -> str:
    origin, args = get_origin(ann), get_args(ann)
    meta = meta or []
    if origin is Annotated:  # its constraints: annotated-types, or a Field's
        inner = [c for m in args[1:] for c in (m.metadata if isinstance(m, FieldInfo) else [m])]
        return _type(args[0], inner + meta)
    if origin in (Union, types.UnionType):
        parts = [_type(a) for a in args if a is not type(None)]
        return " or ".join(dict.fromkeys(parts))
    if origin is Literal:
        return " \\| ".join(f"`{a}`" for a in args)
    if origin is list:
        item = _type(args[0])
        if (n := _length(meta)) is not None:
            return f"{n} {PLURALS.get(item, 'of ' + item)}"
        bounds = _bounds(meta)
        return f"list of {PLURALS.get(item, item)}" + (f" ({bounds})" if bounds else "")
    if origin is dict:
        return "mapping"
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return "section"
    name = {float: "number", int: "integer", str: "text", bool: "true or false"}.get(ann, getattr(ann, "__name__",
                                                                                                str(ann)))
    bounds = _bounds(meta)
    return name + (f" ({bounds})" if bounds else "")


def _default(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        value = field.default_factory()  # type: ignore[call-arg]
        return "its keys' defaults" if isinstance(value, BaseModel) else _value(value)
    return "none" if field.default is None else _value(field.default)


def _value(value: Any) -> str:
    return f"`{json.dumps(value, ensure_ascii=False)}`"


def _tag(model: type[BaseModel]) -> tuple[str, str] | None:
    """A union member's tag: its field whose type is one literal (``type: quintic``)."""
    for name, field in model.model_fields.items():
        if get_origin(field.annotation) is Literal and len(get_args(field.annotation)) == 1:
            return name, str(get_args(field.annotation)[0])
    return None


def rows(model: type[BaseModel], prefix: str = "", variant: tuple[str, str, str] | None = None) -> Iterator[Row]:
    """Every key of ``model`` and of its sections, depth first, in the models' order (a union's members one after
    the other, each row saying which member it belongs to)."""
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        ann = field.annotation
        inner = _models(ann)
        description = " ".join((field.description or "").split())
        if not inner:
            yield Row(key, _type(ann, list(field.metadata)), _default(field), description, False, variant)
            continue
        listed = any(is_list for _, is_list in inner)
        tags = [_tag(m) for m, _ in inner] if len(inner) > 1 else [None] * len(inner)
        kinds = " or ".join(f"{t[0]} `{t[1]}`" for t in tags if t)
        yield Row(key, ("list of sections" if listed else "section") + (f", by {kinds}" if kinds else ""),
                  _default(field), description, True, variant)
        for (sub, is_list), tag in zip(inner, tags, strict=True):
            member = (key, *tag) if tag else variant
            yield from rows(sub, f"{key}[]." if is_list else f"{key}.", member)


def _lookup(data: Any, key: str) -> Any:
    """The value at a dotted key of a file's content (``a[].b``: of the first item of ``a``); KeyError if absent."""
    for part in key.split("."):
        listed = part.endswith("[]")
        data = data[part.removesuffix("[]")]
        if listed:
            if not isinstance(data, list) or not data:
                raise KeyError(key)
            data = data[0]
    return data


def _example(row: Row, shipped: list[tuple[str, Any]]) -> tuple[str, Any] | None:
    """The first shipped scenario (by name) that sets ``row``'s key (in the same member of a union), and its
    value."""
    for name, data in shipped:
        try:
            if row.variant is not None and _lookup(data, f"{row.variant[0]}.{row.variant[1]}") != row.variant[2]:
                continue
            return name, _lookup(data, row.key)
        except (KeyError, TypeError):
            continue
    return None


def reference_markdown() -> str:
    """docs/scenarios.md."""
    from cdpr.config.scenario import ScenarioSpec

    shipped = [(name, read_yaml(resolve(name, "scenarios", "scenario"))) for name in sorted(shipped_names("scenarios"))]
    lines = [
        "# Scenario files: every key",
        "",
        "<!-- GENERATED from the models that validate a scenario (cdpr.config.scenario) by `cdpr scenarios",
        "     --reference > docs/scenarios.md`; tests/test_reference.py fails when this page differs. -->",
        "",
        "A scenario is one YAML file: which robot, which trajectory, which controller, which cable model and",
        "sensors, for how long. Shipped ones are in [`shared/cdpr/scenarios/`](../shared/cdpr/scenarios) (`cdpr",
        "scenarios` lists them); a file of your own is given by its path wherever a scenario's name goes. A key the",
        "models do not know is an error that names it; so is a value out of its bounds (one line: the file, the key,",
        "why; exit code 2).",
        "",
        "**Where a session starts.** At `initial` when the file gives it, else at the trajectory's first pose, at",
        "rest — not at the robot's `home` (the robot's rest pose, which `cdpr show` draws). `cdpr run` and `cdpr up`",
        "say so in one line when the start is not the robot's home.",
        "",
        "Units are SI: m, s, rad, kg, N. A key `a.b` is key `b` of section `a`; `a[].b` is key `b` of each item of the",
        "list `a`. The example is the value of the first shipped scenario (by name) that sets the key.",
        "",
        "| key | type | default | what | example |",
        "|---|---|---|---|---|",
    ]
    for row in rows(ScenarioSpec):
        example = None if row.section else _example(row, shipped)
        shown = "" if example is None else f"{_value(example[1])} ({example[0]})"
        key = f"`{row.key}`" + (f" ({row.variant[1]} `{row.variant[2]}`)" if row.variant else "")
        lines.append(f"| {key} | {row.type} | {row.default} | {row.description.replace('|', chr(92) + '|')} "
                     f"| {shown} |")
    return "\n".join(lines) + "\n"
