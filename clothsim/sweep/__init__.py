"""Parameter sweeps: expand a sweep file into runs, validate them all, run them on local worker
processes or a Dask cluster, and keep every finished run.

The package, by job: :mod:`.spec` (the sweep file, its expansion into runs, their validation),
:mod:`.worker` (one run in a worker process), :mod:`.runs` (run folders, summary.csv, resuming),
:mod:`.executors` (local processes, Dask), :mod:`.plots`, :mod:`.command` (``python app.py
sweep``). The outputs a sweep may tabulate are the field list of :mod:`clothsim.records`.

A sweep file names a base scene (relative to the sweep file), the fields to vary and the outputs
to tabulate and plot::

    base: ../sphere_cap.yaml
    set: {solver.method: paper}          # optional: fixed overrides applied to every run
    sweep:
      mode: grid                         # grid = every combination; zip = element by element
      parameters:
        solver.C: [1.5, 2, 4, 8]
        fabric.divisions: [[10, 10], [20, 20]]
        constraints.0.stretch: {linspace: [1.0, 1.2, 5]}   # 5 values from 1.0 to 1.2
        solver.e: {logspace: [1.0e-8, 1.0e-4, 5]}          # 5 values from 1e-8 to 1e-4, log-spaced
    outputs: [iterations, wall_time_s, max_sensor_pressure_mmhg, friction.slip, probe:ankle_mmhg]

Output folder (``--out``)::

    sweep.yaml                       the sweep file as run
    run-0003-1a2b3c4d/               one folder per run: result.npz, history.csv, sheet.ply,
                                     scene.yaml, sweep_run.json, summary.json (written last)
    summary.csv                      one row per run, rebuilt from the run folders
    plots/<output>__vs__<param>.png  one plot per (output, varied parameter; zip: one parameter),
                                     timings left out unless listed under plots:

Design decisions (why):

* **Run ids** are ``run-<index>-<8 hex of sha1(parameter values)>``: stable across reruns of the
  same sweep file and independent of the executor or of completion order.
* **Workers return the files' bytes; the driver writes them.** A worker runs
  :func:`clothsim.simulation.solve`, saves the Result with :meth:`Result.save` into a private
  temporary folder (so the files are exactly those of a single headless run) and returns their
  bytes. The driver writes each file atomically (temporary name, then rename) into the run folder,
  ``summary.json`` last. This works on a remote Dask cluster without a shared filesystem (only the
  files the scenes reference, such as mold meshes, must be readable by the workers).
* **A finished run is a folder with summary.json.** ``summary.csv`` is rebuilt from the folders,
  so an interrupted sweep (Ctrl-C, killed driver or worker) keeps every finished run and rerunning
  the same command runs only the rest (``--force`` reruns all). A finished run whose scene no
  longer matches what the sweep file now expands to (the base scene was edited) is rerun, and so
  is one that ended in status ``error`` (``--skip-errors`` keeps those).
* **One sweep per folder.** The driver holds ``fcntl.flock`` on ``out/.clothsim.lock``
  (holding its pid) while it runs; a second sweep (or a run or fit) is refused naming that pid. The kernel drops the
  lock with the driver, however it ends, so a stale lock file never blocks.
* **Workers die with the driver.** SIGTERM/SIGHUP act as Ctrl-C (the pool is terminated). Local
  workers (children of the forkserver, not of the driver) set PR_SET_PDEATHSIG and poll the
  driver's pid, so even ``kill -9`` of the driver leaves no worker behind.
* **A full disk** stops the sweep with SweepError (exit 2): free space is checked before each
  run's files are written and a failed write leaves no temporary file.
* **A failing run never stops the sweep.** The worker catches every exception (SceneError,
  MoldError, unexpected ones) and reports status ``error`` with the message; a run that diverges
  or hits a limit keeps its solver status. A worker process that dies is reported as ``crashed``
  (a ``crashed.json`` note, no summary.json), so a rerun retries it.
* **Everything is validated before anything runs**: the sweep file (pydantic), every expanded
  scene and every distinct mold. An error names the run id, the field and the message.
* The local executor uses a ``forkserver`` (``spawn`` where unavailable) process pool. numba's
  on-disk cache (``cache=True`` kernels, stored beside the sources) is shared by all workers: each
  worker loads the compiled kernels instead of compiling them. The worker counts numba cache hits
  and misses per run and the driver reports them.
"""

from __future__ import annotations

from ..fileio import LOCK_FILE  # noqa: F401  (the lock a sweep, run or fit holds on its --out)
from .command import _run_locked, main, run_sweep  # noqa: F401
from .executors import (DASK_CONNECT_TIMEOUT_S, DASK_SCHEMES, PR_SET_PDEATHSIG, Terminated,  # noqa: F401
                        _local_pool, _Progress, _run_dask, _run_local, _terminate_pool, _worker_init,
                        check_dask_address)
from .plots import BOOKKEEPING, make_plots, plot_axes, plot_outputs  # noqa: F401
from .runs import (FINISHED_FILE, _FolderLock, build_summary, finished, read_row, write_crashed,  # noqa: F401
                   write_run)
from .spec import (DEFAULT_OUTPUTS, EXTRA_KEYS, FIT_OUTPUTS, MAX_RUNS, PROBE_OUTPUTS, SUMMARY_KEYS,  # noqa: F401
                   TIMING_KEYS, FitBlock, Run, Space, Sweep, SweepBlock, SweepError, SweepFile, expand,
                   load_sweep, run_id_for, validate_runs)
from .worker import _task, run_one, warm_cache  # noqa: F401
