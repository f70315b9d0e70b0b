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


def shown(value: Any) -> str:
    """A value in a message: a number as short as it is exact (``-5``, ``2.264``, not ``-5.0``, ``2.26400…02``)."""
    if isinstance(value, float) and not isinstance(value, bool):
        return f"{value:.12g}".replace("-0", "0") if value == 0 else f"{value:.12g}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


# pydantic's bounds in the project's words (one wording for a bound, whichever file or option breaks it)
_BOUNDS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="), "less_than": ("lt", "<"),
           "less_than_equal": ("le", "<=")}


def _fields(model: type[BaseModel] | None, loc: tuple[Any, ...]) -> list[str]:
    """The keys a mapping at ``loc`` of ``model`` may hold (to say which one a misspelt key meant)."""
    from typing import get_args

    for part in loc:
        if model is None or isinstance(part, int) or not isinstance(part, str):
            continue
        field = model.model_fields.get(part)
        if field is None:
            return []
        found: type[BaseModel] | None = None
        todo = [field.annotation]
        while todo:
            t = todo.pop()
            if isinstance(t, type) and issubclass(t, BaseModel):
                found = t
                break
            todo.extend(get_args(t))
        model = found
    return list(model.model_fields) if model is not None else []


def describe_validation_error(path: Path | str, exc: ValidationError, model: type[BaseModel] | None = None) -> str:
    """A pydantic ValidationError as ``file: dotted.field: message``, in one wording per kind of error: an unknown
    key first (a misspelt key also makes the key it meant missing), with the key it may have meant."""
    errors = exc.errors()
    err = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
    # Union branches appear in the location as type names ("list[float]"); they are not fields.
    loc = ".".join(str(p) for p in err["loc"] if not (isinstance(p, str) and "[" in p)) or "(top level)"
    msg = err["msg"].removeprefix("Value error, ")
    ctx = err.get("ctx") or {}
    if err["type"] == "missing":
        msg = "missing required key"
    elif err["type"] == "extra_forbidden":
        import difflib

        known = _fields(model, tuple(err["loc"][:-1]))
        near = difflib.get_close_matches(str(err["loc"][-1]), known, n=1, cutoff=0.6)
        msg = f"unknown key (did you mean {near[0]}?)" if near else "unknown key (check its spelling)"
    elif err["type"] in _BOUNDS:
        key, sign = _BOUNDS[err["type"]]
        msg = f"must be {sign} {shown(ctx.get(key))}"
    elif err["type"] in ("finite_number", "float_parsing", "float_type"):
        msg = "must be a finite number"
    if err["type"] not in ("missing", "extra_forbidden") and "input" in err and "(got " not in msg \
            and not isinstance(err["input"], dict):
        msg = f"{msg} (got {shown(err['input'])})"
    return f"{path}: {loc}: {msg}"


def parse_model(model: type[M], data: dict[str, Any], path: Path | str) -> M:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(describe_validation_error(path, exc, model)) from None
