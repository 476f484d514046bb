"""YAML files validated by a pydantic model, failing with one line that names the field.

One implementation for vehicle files, daemon configs and SITL scenarios.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from .errors import ContractError

M = TypeVar("M", bound=BaseModel)


def one_line(err: ValidationError) -> str:
    """The first validation error as `field.path: message (got value) [+N more]`."""
    e = err.errors()[0]
    where = ".".join(str(p) for p in e["loc"]) or "(top level)"
    msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"].removeprefix("Value error, ")
    got = "" if e["type"] in ("missing", "value_error", "extra_forbidden") else f" (got {e.get('input')!r})"
    more = f" [+{len(err.errors()) - 1} more]" if len(err.errors()) > 1 else ""
    return f"{where}: {msg}{got}{more}"


def model_from_dict(model: type[M], data: object, source: str, error: type[Exception] = ContractError,
                    empty_ok: bool = False) -> M:
    """Validate a mapping; `error(f"{source}: …")` with one line if it does not fit."""
    if data is None and empty_ok:
        data = {}
    if not isinstance(data, dict):
        raise error(f"{source}: expected a mapping")
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise error(f"{source}: {one_line(err)}") from None


def resolve_named(name_or_path: str | Path, directory: Path) -> Path:
    """A path as given, or a shipped file by name (`mambo` → `<directory>/mambo.yaml`)."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return directory / f"{p.name}.yaml"


def load_model(model: type[M], path: str | Path, what: str, error: type[Exception] = ContractError,
               empty_ok: bool = False) -> M:
    """Read, parse and validate a YAML file; every failure is one `error` line naming the file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise error(f"{what} {path}: cannot read ({err.strerror or err})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise error(f"{what} {path}:{where} is not valid YAML") from None
    return model_from_dict(model, data, f"{what} {path.name}", error, empty_ok)
