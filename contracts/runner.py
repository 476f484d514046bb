"""Running sweep tasks: a local process pool by default, a Dask distributed cluster when given a scheduler
address (DESIGN.md §4.6), with a progress bar. Used by the avoid sweep (`contracts.sweep`) and the
controller-contract sweep (`sitl_harness.etr_sweep`); imports no solver.
"""

from __future__ import annotations

import concurrent.futures as cf
import os

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}  # per worker process


def run_tasks(tasks, workers, scheduler, progress, total, fn, desc="tasks"):
    """Run `fn(task) -> list` over `tasks` on a local process pool (`workers` > 1), in-process
    (`workers` ≤ 1) or on a Dask distributed cluster (`scheduler` address); a tqdm bar counts the
    items of the returned lists up to `total`. `fn` must be a module-level function (picklable).
    Results come back in task order."""
    from tqdm import tqdm

    results = [None] * len(tasks)
    bar = tqdm(total=total, desc=desc, unit="cell", disable=not progress)
    if scheduler:
        from distributed import Client, as_completed

        with Client(scheduler) as client:
            futs = {client.submit(fn, t, pure=False): i for i, t in enumerate(tasks)}
            for f in as_completed(list(futs)):
                results[futs[f]] = f.result()
                bar.update(len(results[futs[f]]))
    elif workers <= 1:
        for i, t in enumerate(tasks):
            results[i] = fn(t)
            bar.update(len(results[i]))
    else:
        for k, v in ONE_THREAD.items():  # one solver thread per worker process (inherited at spawn)
            os.environ.setdefault(k, v)
        import multiprocessing as mp

        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
            futs = {ex.submit(fn, t): i for i, t in enumerate(tasks)}
            for f in cf.as_completed(futs):
                results[futs[f]] = f.result()
                bar.update(len(results[futs[f]]))
    bar.close()
    return results
