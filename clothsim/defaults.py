"""The solvers' defaults, kept in one place below both the scene layer and the solvers: the scene
file's ``solver:`` section (``config.SolverSettings``), the run limits and solver options
(``solvers.base.settings_default``) and the viewer's Solver tab all read this table."""

from __future__ import annotations

#: name -> default of ``solver.<name>`` (units: C dimensionless > 1; e [N]; time_limit_s [s] or
#: None for no limit; newton_kink a fraction of a table's first slope; the rest counts)
SOLVER_DEFAULTS: dict = {
    "method": "auto",
    "C": 2.0,
    "e": 1e-6,
    "max_iterations": 200_000,
    "time_limit_s": None,
    "max_retries": 60,
    "stall_iterations": 2000,
    "newton_kink": 1e-3,
    "newton_sequencing": True,
    "load_steps": 1,
}
