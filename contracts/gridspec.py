"""One axis of a sweep grid as a person writes it in a grid YAML file (`table build --grid`,
`table etr --grid`): a list, a single number, or a mapping `{min, max, n}` / `{min, max, step}`
(`spacing: geometric` for a geometric `n`). No solver imports: the E_tr sweep uses it too."""

from __future__ import annotations

import numpy as np
import yaml

from .errors import ContractError


def axis(spec, name, deg=False, span: tuple[float, float] | None = None) -> np.ndarray:
    """The axis values (radians when `deg`). In a mapping, `min` and `max` default to `span` (the vehicle's
    range for this axis, so a grid file need not repeat the vehicle file); `n: 1` is the top end."""
    if isinstance(spec, (list, tuple)):
        vals = np.asarray(spec, dtype=float)
    elif isinstance(spec, dict):
        known = {"min", "max", "n", "step", "spacing"}
        if set(spec) - known or not {"n", "step"} & set(spec):
            raise ContractError(f"grid: {name} takes min, max (default: the vehicle's) and n or step")
        if span is None and not {"min", "max"} <= set(spec):
            raise ContractError(f"grid: {name} needs min and max")
        lo, hi = (float(spec[k]) if k in spec else float(d) for k, d in zip(("min", "max"), span or (0, 0)))
        if "step" not in spec and int(spec["n"]) == 1:
            vals = np.asarray([hi])
        elif "step" in spec:
            vals = np.arange(lo, hi + 0.5 * float(spec["step"]), float(spec["step"]))
            vals = np.round(vals, 10)
        else:
            n = int(spec["n"])
            vals = np.geomspace(lo, hi, n) if spec.get("spacing", "linear") == "geometric" else np.linspace(lo, hi, n)
    elif isinstance(spec, (int, float)):
        vals = np.asarray([float(spec)])
    else:
        raise ContractError(f"grid: {name} must be a list or a mapping with min/max and n or step")
    if vals.size == 0 or not np.all(np.isfinite(vals)) or np.any(np.diff(vals) <= 0):
        raise ContractError(f"grid: {name} must be finite and strictly increasing")
    return np.radians(vals) if deg else vals


def vehicle_spans(vehicle) -> dict:
    """What a grid axis given as `{n: N}` (no min/max) spans: the vehicle's thrust range, 3°…its tilt limit."""
    return {"tilt_deg": (3.0, vehicle.tilt_max_deg), "thrust_ratio": tuple(vehicle.thrust_ratio_range)}


def load_mapping(path, what: str = "grid file") -> dict:
    """A grid YAML file as a mapping (an empty file is an empty mapping), or one `ContractError` line."""
    from pathlib import Path

    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise ContractError(f"{what} {path}: cannot read ({err.strerror or err})") from None
    except yaml.YAMLError:
        raise ContractError(f"{what} {path}: not valid YAML") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ContractError(f"{what} {path}: expected a mapping")
    return data


def as_grid(grid, vehicle, default, from_dict, what: str = "grid file"):
    """The grid a build was given: a grid object as is, a mapping through `from_dict(mapping, vehicle)`, a
    YAML path loaded first, None → `default(vehicle)`."""
    from pathlib import Path

    if grid is None:
        return default(vehicle)
    if isinstance(grid, (str, Path)):
        grid = load_mapping(grid, what)
    return from_dict(grid, vehicle) if isinstance(grid, dict) else grid
