"""contract-guard's ground floor: vehicle files, flat-model maths, planners, the Γ table.

Nothing here imports `companion` or `sitl_harness`; the table reader and the flat maths are
used on board, so they must never import CasADi (only `contracts.planner` and the sweeps may).
"""

__version__ = "0.1.0"
