"""Every file a person can pass ends in one clear line and a non-zero exit — binary, not UTF-8, endless,
huge, an alias bomb, nested past reason (issue 17, item 11). Real processes; the timeout only guards
against a hang (speed is measured in benchmarks/bench_bad_files.py)."""

import subprocess
import sys
from pathlib import Path

import pytest

from companion.onboard.config import load_config
from contracts.errors import ContractError
from contracts.vehicle import load_vehicle
from contracts.yamlfile import parse_yaml
from sitl_harness.scenario import ScenarioError, load_scenario

ROOT = Path(__file__).resolve().parents[1]
MAMBO_TABLE = ROOT / "contracts" / "data" / "mambo.npz"


def alias_bomb(levels: int) -> str:
    """A few hundred bytes that expand to 10**levels elements."""
    lines = ['a0: &a0 ["x","x","x","x","x","x","x","x","x","x"]']
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ",".join([f"*a{k - 1}"] * 10) + "]")
    return "\n".join(lines) + f"\nsensors: *a{levels - 1}\n"


BAD = {
    "binary": lambda p: p.write_bytes(bytes(range(256)) * 8),
    "not_utf8": lambda p: p.write_bytes("mode: governor\nvehicle: caf\xe9\n".encode("latin-1")),
    "huge_sparse": lambda p: open(p, "wb").truncate(300 * 1024 * 1024),  # 300 MB of zeros, sparse on disk
    "huge_text": lambda p: p.write_text("# padding\n" * 200_000),
    "alias_bomb_9": lambda p: p.write_text(alias_bomb(9)),  # 10⁹ elements under a real key
    "alias_bomb_5": lambda p: p.write_text(alias_bomb(5)),  # 10⁵ elements: small in bytes, refused even so
    "deep": lambda p: p.write_text("[" * 20_000 + "]" * 20_000),
    "dev_zero": None,  # endless
    "directory": None,
}


def bad_file(kind: str, tmp_path: Path) -> Path:
    if kind == "dev_zero":
        return Path("/dev/zero")
    if kind == "directory":
        return tmp_path
    p = tmp_path / f"{kind}.yaml"
    BAD[kind](p)
    return p


LOADERS = {
    "config": lambda f: load_config(f),
    "scenario": lambda f: load_scenario(str(f)),
    "vehicle": lambda f: load_vehicle(str(f)),
}


@pytest.mark.parametrize("kind", list(BAD))
@pytest.mark.parametrize("what", list(LOADERS))
def test_a_bad_file_is_refused_in_one_line(what, kind, tmp_path):
    f = bad_file(kind, tmp_path)
    with pytest.raises((ContractError, ScenarioError)) as err:
        LOADERS[what](f)
    msg = str(err.value)
    assert "\n" not in msg and (f.name in msg or str(f) in msg), msg


def test_the_alias_limit_counts_expansion_not_bytes():  # and a normal file with aliases still loads
    assert parse_yaml("a: &x [1, 2]\nb: *x\n") == {"a": [1, 2], "b": [1, 2]}
    assert len(alias_bomb(9)) < 700
    with pytest.raises(ValueError, match="expands"):
        parse_yaml(alias_bomb(9))


COMMANDS = {
    "run --config": lambda f: ["run", "--config", f],
    "sitl --scenario": lambda f: ["sitl", "--scenario", f],
    "table verify --vehicle": lambda f: ["table", "verify", MAMBO_TABLE, "--vehicle", f],
}


@pytest.mark.parametrize("kind", ["not_utf8", "dev_zero", "alias_bomb_9"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_bad_file_is_one_line_and_a_non_zero_exit(command, kind, tmp_path):
    f = bad_file(kind, tmp_path)
    r = subprocess.run([sys.executable, "-m", "companion.cli", *map(str, COMMANDS[command](f))],
                       capture_output=True, text=True, cwd=ROOT, timeout=120, stdin=subprocess.DEVNULL)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr[-2000:]
    assert str(f.name) in lines[0] or str(f) in lines[0]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "x"])
def test_a_non_finite_number_on_the_command_line_is_refused(value):
    r = subprocess.run([sys.executable, "-m", "companion.cli", "table", "query", str(MAMBO_TABLE), "--d-od", "6",
                        "--r-obst", "1", "--e-tr", "0.3", "--thrust-ratio", "1", "--v-max", value],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--v-max" in lines[0], r.stderr
