"""Many runs at once: every log under every configuration of a parameter grid.

:mod:`~bioslam.batch.grid` expands a TOML grid into configurations, :mod:`~bioslam.batch.task`
is one run as a self-contained function, :mod:`~bioslam.batch.engines` carries the runs out on
Ray or a local process pool, :mod:`~bioslam.batch.results` writes the results table and
:mod:`~bioslam.batch.runner` ties them together (resume, progress, Ctrl-C).
"""

from bioslam.batch.grid import GridPoint, expand_grid, load_grid
from bioslam.batch.runner import BatchReport, BatchSpec, run_batch

__all__ = ["BatchReport", "BatchSpec", "GridPoint", "expand_grid", "load_grid", "run_batch"]
