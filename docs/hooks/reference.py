"""MkDocs hook: the configuration and command-line reference pages, written at build time from the code
itself, so they never go stale.

- `reference/config.md` from the pydantic models of `companion/onboard/config.py`: every key with its type, default,
  allowed range and the comment beside it in the source (or above it);
- `reference/cli.md` from the argparse parser of `companion/cli.py` (and the SITL's own parser): every
  command's `--help` page.

`mkdocs build` (and `mkdocs serve`) run it (`hooks:` in mkdocs.yml); `python docs/hooks/reference.py DIR`
writes the two pages into DIR without MkDocs.
"""

from __future__ import annotations

import argparse
import inspect
import io
import os
import re
import sys
import tokenize
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PAGES = {"reference/config.md": "config_page", "reference/cli.md": "cli_page"}


# ----------------------------------------------------------------------------- configuration


def field_comments(cls) -> dict[str, str]:
    """The comment of each field of a pydantic model class, from its source: the comment at the end of the
    field's line, else the comment lines right above it."""
    src = inspect.getsource(cls)
    out, above = {}, []
    lines = src.splitlines()
    comments = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    for n, line in enumerate(lines, 1):
        m = re.match(r"    (\w+):", line)
        stripped = line.strip()
        if stripped.startswith("#"):
            above.append(comments.get(n, ""))
            continue
        if m and m.group(1) in cls.model_fields:
            text = comments.get(n) or " ".join(above)
            out[m.group(1)] = text
        above = []
    return out


def type_name(annotation) -> str:
    """A field's type as a person reads it: `float`, `one of shadow, governor`, `list of int`, `path`."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return "one of " + ", ".join(f"`{a}`" for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        parts = [type_name(a) for a in args if a is not type(None)]
        return " or ".join(parts) + (" or none" if type(None) in args else "")
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin in (list, tuple):
        inner = [type_name(a) for a in args if a is not Ellipsis]
        if origin is tuple and len(inner) > 1:
            return f"[{', '.join(inner)}]"
        return f"list of {inner[0]}" if inner else "list"
    if isinstance(annotation, type):
        from pydantic import BaseModel

        if issubclass(annotation, BaseModel):
            return "mapping"
        return {"str": "text", "bool": "true/false", "Path": "path", "PosixPath": "path"}.get(annotation.__name__,
                                                                                          annotation.__name__)
    return str(annotation).replace("typing.", "")


def bounds(field) -> str:
    """The allowed range a field's constraints state (`> 0`, `0 … 0.9`)."""
    marks = []
    for m in field.metadata:
        for attr, sym in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"), ("min_length", "at least")):
            v = getattr(m, attr, None)
            if v is not None:
                marks.append(f"{sym} {v}" + (" items" if attr == "min_length" else ""))
    return ", ".join(marks)


def nested_model(annotation):
    from pydantic import BaseModel

    for a in (annotation, *typing.get_args(annotation)):
        a = typing.get_args(a)[0] if typing.get_origin(a) is list else a
        if isinstance(a, type) and issubclass(a, BaseModel):
            return a
    return None


def default_text(field) -> str:
    from pydantic_core import PydanticUndefined

    if field.is_required():
        return "**required**"
    d = field.default
    if d is PydanticUndefined or d is None:
        return "none" if d is None else ""
    if hasattr(d, "model_dump"):
        return "(see below)"
    if isinstance(d, bool):
        return f"`{str(d).lower()}`"  # as YAML spells it
    if isinstance(d, (list, tuple)):
        return f"`{list(d)}`" if d else "`[]`"
    return f"`{d}`"


def model_rows(cls, prefix: str, sections: list):
    comments = field_comments(cls)
    rows = []
    for name, field in cls.model_fields.items():
        key = f"{prefix}{name}"
        sub = nested_model(field.annotation)
        what = comments.get(name, "")
        if sub is not None:
            is_list = "list" in type_name(field.annotation)
            sections.append((f"{key}[]" if is_list else key, sub))
            what = (what + " " if what else "") + f"see [`{key}`](#{anchor(key)})"
        rng = bounds(field)
        what = what.replace("|", "\\|")
        rows.append(f"| `{key}` | {type_name(field.annotation)}{f' ({rng})' if rng else ''} | {default_text(field)} | "
                    f"{what} |")
    return rows


def anchor(key: str) -> str:
    return re.sub(r"[^a-z0-9_-]", "", key.lower().replace(".", "").replace("[]", ""))


def config_page() -> str:
    from companion.onboard.config import Config

    out = ["# Configuration reference", "",
           "Generated from the pydantic models in `companion/onboard/config.py` when the site is built. The daemon's config "
           "is one YAML file (`contract-guard run --config FILE`), validated on load: an unknown key or a bad value "
           "ends the daemon with one line naming the key and exit status 2. Units are SI; degrees only where a key "
           "ends in `_deg`. Relative paths in a config are relative to the config file's own directory. Worked "
           "examples: `examples/px4-udp.yaml`, `examples/ardupilot-serial.yaml`, `examples/offboard-mission.yaml`, "
           "`examples/raspberry-pi.yaml`, `examples/sitl-px4.yaml`; `contract-guard run --config FILE --check` "
           "validates one without opening the link.", ""]
    sections, done = [("", Config)], set()
    while sections:
        key, cls = sections.pop(0)
        if key in done:
            continue
        done.add(key)
        out += [f"## `{key}` {{#{anchor(key)}}}" if key else "## Top level", ""]
        doc = inspect.cleandoc(cls.__dict__.get("__doc__") or "")
        if doc:
            out += [doc.replace("\n", " "), ""]
        out += ["| key | type | default | what it is |", "|---|---|---|---|"]
        prefix = key.replace("[]", "[k]") + "." if key else ""
        out += model_rows(cls, prefix, sections)
        out.append("")
    return "\n".join(out)


# ----------------------------------------------------------------------------- command line


def parsers():
    """(`contract-guard WORDS`, parser) for every command, in the parser's order."""
    from companion.cli import build_parser
    from sitl_harness.__main__ import build_parser as sitl_parser

    def walk(p, words):
        yield words, p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    if name == "sitl":
                        yield ["sitl"], sitl_parser("contract-guard sitl")
                    elif name == "calibrate-plan":
                        yield ["calibrate", "plan"], sub
                    else:
                        yield from walk(sub, [*words, name])

    yield from walk(build_parser(), [])


def cli_page() -> str:
    os.environ["COLUMNS"] = "100"  # argparse wraps at the terminal's width: the same page on every machine
    out = ["# Command-line reference", "",
           "Generated from the argparse parser in `companion/cli.py` when the site is built: each section is that "
           "command's `--help`. Every command that prints results takes `--json` (one JSON object on stdout); an "
           "error a person can cause ends with one line on stderr and exit status 2, never a traceback.", ""]
    for words, p in parsers():
        title = " ".join(["contract-guard", *words])
        out += [f"## `{title}`", ""]
        if words and p.description:
            out += [p.description, ""]
        out += ["```text", p.format_help().rstrip(), "```", ""]
    return "\n".join(out)


# ----------------------------------------------------------------------------- MkDocs


def on_files(files, config):
    """Add the generated pages to the site (nothing is written into docs/)."""
    from mkdocs.structure.files import File

    for uri, fn in PAGES.items():
        files.append(File.generated(config, uri, content=globals()[fn]()))
    return files


if __name__ == "__main__":
    dest = Path(sys.argv[1] if len(sys.argv) > 1 else "site-reference")
    for uri, fn in PAGES.items():
        (dest / uri).parent.mkdir(parents=True, exist_ok=True)
        (dest / uri).write_text(globals()[fn]())
        print(dest / uri)
