"""Only the planner and the sweep may import CasADi; the reader, the plot and the estimate must not."""

import subprocess
import sys


def test_onboard_and_plot_modules_do_not_import_casadi():
    code = ("import sys, contracts.table, contracts.lookup, contracts.avoid_plot, contracts.avoid_limit, "
            "contracts.online_planner, contracts.runner, contracts.trajectories, companion.onboard.guidance, "
            "companion.onboard.supervisor; "
            "assert 'casadi' not in sys.modules, 'casadi imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_sweep_does_import_casadi():  # the check above can fail
    code = "import sys, contracts.sweep; assert 'casadi' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_harness_does_not_import_the_companion():  # DESIGN.md §3: the online planner lives in contracts/
    code = ("import sys, sitl_harness.etr_sweep, sitl_harness.demo_flights; "
            "assert not [m for m in sys.modules if m.split('.')[0] == 'companion'], 'companion imported'")
    subprocess.run([sys.executable, "-c", code], check=True)
