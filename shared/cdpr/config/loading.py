"""Reading YAML data files (robots, scenarios) into validated models, with one-line errors.

A file that cannot be used raises :class:`cdpr.errors.InputError` whose message names the file and
the field, e.g. ``robots/bad.yaml: platform.mass: must be > 0 (got -1.0)``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from cdpr.errors import InputError


class Strict(BaseModel):
    """The base of every file's model: unknown keys are errors (a misspelt key must not pass), values frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)

M = TypeVar("M", bound=BaseModel)


def shipped_names(folder: str) -> list[str]:
    """Names (file stems) of the YAML files shipped in the package folder ``cdpr/<folder>``."""
    root = resources.files("cdpr") / folder
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def resolve(name_or_path: str | Path, folder: str, what: str) -> Path:
    """A shipped name (``caroca``) or a path to a YAML file → the file's path."""
    text = str(name_or_path)
    if text.endswith((".yaml", ".yml")) or "/" in text or Path(text).is_file():
        path = Path(text)
        if not path.is_file():
            raise InputError(f"{text}: no such {what} file")
        return path
    candidate = resources.files("cdpr") / folder / f"{text}.yaml"
    if not candidate.is_file():
        known = ", ".join(shipped_names(folder))
        raise InputError(f"{text}: unknown {what} (shipped: {known}; or give a path to a .yaml file)")
    return Path(str(candidate))


def read_yaml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise InputError(f"{path}: not valid YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return data


def describe_validation_error(path: Path | str, exc: ValidationError) -> str:
    """The first error of a pydantic ValidationError as ``file: dotted.field: message``."""
    err = exc.errors()[0]
    # Union branches appear in the location as type names ("list[float]"); they are not fields.
    loc = ".".join(str(p) for p in err["loc"] if not (isinstance(p, str) and "[" in p)) or "(top level)"
    msg = err["msg"]
    if err["type"] == "missing":
        msg = "missing required key"
    elif err["type"] == "extra_forbidden":
        msg = "unknown key (check its spelling)"
    elif "input" in err and "(got " not in msg and not isinstance(err["input"], dict):
        shown = repr(err["input"])
        if len(shown) > 60:
            shown = shown[:57] + "..."
        msg = f"{msg} (got {shown})"
    msg = msg.removeprefix("Value error, ")
    return f"{path}: {loc}: {msg}"


def parse_model(model: type[M], data: dict[str, Any], path: Path | str) -> M:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(describe_validation_error(path, exc)) from None
