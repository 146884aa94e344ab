"""Work-precision: the feedback integrator against every method a user could pick (see :mod:`liefi.bench.core`).

* :mod:`~liefi.bench.core`: the tasks, one run (:func:`run_task`), its errors and
  drifts (:func:`measure`), the sweep (:func:`work_precision`, every run
  appended to a :class:`~liefi.results.sweep.ResultStore` as it finishes), the CSV and
  the timings (best of :data:`REPEATS`);
* :mod:`~liefi.bench.verdict`: the verdict (:func:`summarize`: per criterion --
  drift only, and accurate: error and drift -- the cheapest run, the cheapest
  FI, ``fi_over_best`` and ``fi_over_best_accurate``, win/tie/loss against the
  measured noise; :func:`rtol_vs_best` for the ``FI-rtol`` runs);
* :mod:`~liefi.bench.horizon`: long horizons -- drift against time at matched
  cost, and the crossover horizon beyond which the FI is the cheapest way to
  keep the invariants (:func:`crossover`);
* :mod:`~liefi.bench.plots`: the diagrams (matplotlib imported on use);
* :mod:`~liefi.bench.cli`: ``liefi bench`` (also ``python -m liefi.bench``).
"""

from .cli import add_arguments, main, run_from_args, write_summary
from .core import (FI_GAINS, FI_RTOLS, FIXED_SCHEMES, IVP_METHODS, METHODS, REPEATS, applicable_methods, best_of,
                   build_tasks, default_fi_rtols, default_grid, error_row, invariant_drifts, measure, read_csv,
                   reference, run_task, work_precision, write_csv)
from .horizon import (HORIZONS, cost_curves, crossover, horizon_row, horizon_tasks, long_horizon, matched_tasks,
                      plot_cost_vs_horizon)
from .plots import load_curves, plot, plot_long_horizon, save_curves
from .verdict import (ACCURATE_DRIFT, ACCURATE_ERROR, DRIFT, FI_METHODS, RTOL_METHOD, cheapest, compare,
                      interpolated_cpu, rtol_vs_best, scene_noise, summarize, summary)

__all__ = [
    "FI_GAINS", "FI_METHODS", "FI_RTOLS", "FIXED_SCHEMES", "IVP_METHODS", "METHODS", "HORIZONS", "REPEATS",
    "ACCURATE_DRIFT", "ACCURATE_ERROR", "DRIFT", "RTOL_METHOD",
    "default_grid", "default_fi_rtols", "best_of", "compare", "interpolated_cpu", "rtol_vs_best", "scene_noise", "applicable_methods", "build_tasks", "run_task", "reference", "measure", "invariant_drifts",
    "error_row", "work_precision", "write_csv", "read_csv", "cheapest", "summarize", "summary", "plot",
    "matched_tasks", "long_horizon", "horizon_tasks", "horizon_row", "cost_curves", "crossover",
    "plot_cost_vs_horizon", "plot_long_horizon", "save_curves", "load_curves",
    "add_arguments", "run_from_args", "write_summary", "main",
]
