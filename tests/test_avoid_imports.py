"""Only the planner and the sweep may import CasADi; the reader, the plot and the estimate must not."""

import subprocess
import sys


def test_onboard_and_plot_modules_do_not_import_casadi():
    code = ("import sys, contracts.table, contracts.lookup, contracts.avoid_plot, contracts.avoid_limit; "
            "assert 'casadi' not in sys.modules, 'casadi imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_sweep_does_import_casadi():  # the check above can fail
    code = "import sys, contracts.sweep; assert 'casadi' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
