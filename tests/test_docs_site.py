"""The manual: the MkDocs site builds with `--strict` (a broken link, a missing page or anchor, a page left out
of the navigation fails), its reference pages are generated from the code and complete, the README stays
short, and nothing in the user documentation points outside the repository or speaks in internal jargon."""

import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
USER_DOCS = [README, *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "examples").rglob("*.yaml"))]
sys.path.insert(0, str(ROOT / "docs" / "hooks"))
import reference  # noqa: E402  (docs/hooks/reference.py, the MkDocs hook)


def test_the_site_builds_strictly(tmp_path):
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                       cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    for page in ("index.html", "getting-started/index.html", "reference/config/index.html",
                 "reference/cli/index.html", "evidence/index.html"):
        assert (tmp_path / "site" / page).is_file(), page
    assert not (tmp_path / "site" / "hooks").exists()  # the hook is not published


def config_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    keys = []
    for name, field in model.model_fields.items():
        keys.append(prefix + name)
        for a in (field.annotation, *typing.get_args(field.annotation)):
            is_list = typing.get_origin(a) is list
            a = typing.get_args(a)[0] if is_list else a
            if isinstance(a, type) and issubclass(a, BaseModel):
                keys += config_keys(a, f"{prefix}{name}{'[k]' if is_list else ''}.")
                break
    return keys


def test_the_configuration_reference_has_every_key_with_its_default():
    from companion.onboard.config import Config, ContractConfig

    page = reference.config_page()
    keys = config_keys(Config)
    assert len(keys) > 50
    for key in keys:
        assert f"| `{key}` |" in page, key
    # a default and a constraint read from the model, not written by hand
    assert f"| `contract.dwell_s` | float (≥ 0.5, ≤ 600.0) | `{ContractConfig.model_fields['dwell_s'].default}` |" in page
    assert "| `sensors[k].h_fov_deg` | float (> 0, ≤ 360) | **required** |" in page


def test_the_cli_reference_has_every_command_and_option():
    from companion.cli import build_parser

    page = reference.cli_page()
    for words, parser in reference.parsers():
        assert f"## `{' '.join(['contract-guard', *words])}`" in page
        for action in parser._actions:
            for opt in action.option_strings:
                assert opt in page, (words, opt)
    assert "--partial-grid" in page and "--check" in page and build_parser().prog == "contract-guard"


def test_the_readme_is_short_and_keeps_the_two_commands():
    text = README.read_text()
    assert len(text.encode()) <= 12 * 1024
    assert "make demo" in text and "make test" in text
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        assert (ROOT / target).exists(), target


FORBIDDEN = re.compile(r"shared/|DESIGN\.md|\bissue [0-9]+|as the issue says|\bsession\b", re.IGNORECASE)


@pytest.mark.parametrize("path", USER_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_outside_the_repository_and_no_jargon(path):
    hits = [f"{n}: {ln.strip()}" for n, ln in enumerate(path.read_text().splitlines(), 1) if FORBIDDEN.search(ln)]
    assert not hits, hits


def test_the_generated_pages_carry_no_jargon_either():
    """They are made of the code's comments and help strings."""
    for page in (reference.config_page(), reference.cli_page()):
        assert not [ln for ln in page.splitlines() if FORBIDDEN.search(ln)]


REPO_PATH = re.compile(r"`((?:examples|contracts|companion|sitl_harness|benchmarks|systemd|tests|docs)/[\w./-]+)")


@pytest.mark.parametrize("path", [p for p in USER_DOCS if p.suffix == ".md"], ids=lambda p: p.name)
def test_the_files_the_docs_name_exist(path):
    """A file a page names in backticks (`examples/px4-udp.yaml`) is in the repository."""
    missing = [p for p in REPO_PATH.findall(path.read_text())
               if not any(c in p for c in "*{")
               and not (ROOT / p.rstrip(".")).exists()
               and not re.search(r"\.(npz|partial)$|-log/?$|/$", p.rstrip("."))]  # outputs the page's commands write
    assert not missing, missing
