"""YAML files validated by a pydantic model, failing with one line that names the field.

One implementation for vehicle files, daemon configs and SITL scenarios; a key stated twice in one mapping is
refused (one line naming it and its lines), never the last one taken. Whatever file a person passes —
binary, not UTF-8, endless (`/dev/zero`), huge, an alias bomb, nested past reason — ends in one line
within a second: the file is read to at most `MAX_BYTES`, and a document expanding (aliases counted
each time they are used) to more than `MAX_NODES` nodes is refused before it is built.
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
                    empty_ok: bool = False, context: dict | None = None) -> M:
    """Validate a mapping (`context`: pydantic's validation context); `error(f"{source}: …")` with one line
    if it does not fit."""
    if data is None and empty_ok:
        data = {}
    if not isinstance(data, dict):
        raise error(f"{source}: expected a mapping")
    try:
        return model.model_validate(data, context=context)
    except ValidationError as err:
        raise error(f"{source}: {one_line(err)}") from None


def resolve_named(name_or_path: str | Path, directory: Path) -> Path:
    """A path as given, or a shipped file by name (`mambo` → `<directory>/mambo.yaml`)."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return directory / f"{p.name}.yaml"


MAX_BYTES = 512 * 1024  # no vehicle file, config or scenario comes near it; parsed in well under a second
MAX_NODES = 100_000  # YAML nodes after alias expansion


def read_bounded(path: str | Path, what: str, limit: int = MAX_BYTES, error: type[Exception] = ContractError) -> bytes:
    """A file's bytes, at most `limit` of them (a larger or endless file is one `error` line)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as err:
        raise error(f"{what} {path}: cannot read ({err.strerror or err})") from None
    if len(data) > limit:
        raise error(f"{what} {path}: larger than {limit // 1024} KiB: not a {what}") from None
    return data


def _expanded_size(node, memo: dict) -> int:
    """Nodes in the document once every alias is expanded (each anchored node counted where it is used)."""
    key = id(node)
    if key not in memo:
        memo[key] = 0  # a node that contains itself: counted once
        if isinstance(node, yaml.MappingNode):
            n = 1 + sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
        elif isinstance(node, yaml.SequenceNode):
            n = 1 + sum(_expanded_size(v, memo) for v in node.value)
        else:
            n = 1
        memo[key] = min(n, MAX_NODES + 1)
    return memo[key]


def _duplicate_key(node, seen: set) -> str | None:
    """The first mapping key stated twice in one mapping, as `'key' (line N, first at line M)`; None if none.
    YAML says a mapping's keys are unique, but a loader keeps the last silently: a second `obstacle_s:` further
    down would quietly undo the first."""
    if id(node) in seen:
        return None
    seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        first: dict = {}
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.tag != "tag:yaml.org,2002:merge":
                if k.value in first:
                    return f"{k.value!r} (line {k.start_mark.line + 1}, first at line {first[k.value] + 1})"
                first[k.value] = k.start_mark.line
            found = _duplicate_key(k, seen) or _duplicate_key(v, seen)
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for v in node.value:
            found = _duplicate_key(v, seen)
            if found:
                return found
    return None


def parse_yaml(text: str) -> object:
    """`yaml.safe_load`, refusing a document that expands past MAX_NODES or states a key twice in one mapping
    (ValueError)."""
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)(text)  # libyaml where built in: 10× faster
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if _expanded_size(node, {}) > MAX_NODES:
            raise ValueError(f"expands to more than {MAX_NODES} YAML nodes (aliases?)")
        dup = _duplicate_key(node, set())
        if dup:
            raise ValueError(f"duplicate key {dup}")
        return loader.construct_document(node)
    finally:
        loader.dispose()


def load_model(model: type[M], path: str | Path, what: str, error: type[Exception] = ContractError,
               empty_ok: bool = False, context: dict | None = None) -> M:
    """Read, parse and validate a YAML file; every failure is one `error` line naming the file."""
    path = Path(path)
    raw = read_bounded(path, what, error=error)
    if b"\0" in raw:
        raise error(f"{what} {path}: a binary file, not YAML") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"{what} {path}: not UTF-8 text (byte {err.start})") from None
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise error(f"{what} {path}:{where} is not valid YAML") from None
    except (ValueError, RecursionError) as err:
        why = "nested too deeply" if isinstance(err, RecursionError) else str(err)
        raise error(f"{what} {path}: refused: {why}") from None
    return model_from_dict(model, data, f"{what} {path.name}", error, empty_ok, context)
