"""Running sweep tasks: a local process pool by default, a Dask distributed cluster when given a scheduler
address (DESIGN.md §4.6), with a progress bar and an optional checkpoint. Used by the avoid sweep
(`contracts.sweep`) and the controller-contract sweep (`sitl_harness.etr_sweep`); imports no solver.

A checkpoint (`Checkpoint`) keeps every finished task's result beside the build's output, in
`<out>.partial/`, written as it arrives: an interrupted build (Ctrl-C, SIGTERM, a crash, a power cut)
loses at most the tasks that were running, and the same command with `--resume` flies only the rest.
The results are the same as those of an uninterrupted build because every task is a pure function of
its inputs (which the checkpoint's key pins) and results are assembled in task order.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import os
import pickle
import shutil
import signal
from pathlib import Path

from .errors import ContractError

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}  # per worker process


class BuildInterrupted(ContractError):
    """A build stopped by a signal; its finished tasks are in the checkpoint (if any)."""


def checkpoint_path(out) -> Path:
    """Where the checkpoint of a build writing `out` lives: `<out>.partial/` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".partial")


class Checkpoint:
    """The finished tasks of one build, one pickle per task index under `<out>.partial/`, plus
    `key.json`: what the results depend on (vehicle fingerprint, grid, solver settings, table hash).
    A resume with another key is refused, so a checkpoint never mixes two builds."""

    def __init__(self, out, key: dict, resume: bool, command: str = "the same command"):
        self.dir = checkpoint_path(out)
        self.key = key
        self.digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
        self.resumed_items = 0  # cells (items of the task results) taken from the checkpoint
        found = (self.dir / "key.json").is_file()
        if found and not resume:
            raise ContractError(f"{self.dir} holds the checkpoint of an interrupted build: add --resume to {command} "
                                f"to continue it, or delete that folder to start again")
        if found:
            try:
                old = json.loads((self.dir / "key.json").read_text()).get("sha256")
            except (OSError, ValueError):
                old = None
            if old != self.digest:
                raise ContractError(f"{self.dir}: the checkpoint is of a build with another vehicle, grid or table; "
                                    f"delete that folder to start again")
        else:
            if self.dir.exists():
                shutil.rmtree(self.dir)
            self.dir.mkdir(parents=True)
            self._write(self.dir / "key.json", json.dumps({"sha256": self.digest, "key": self.key}, default=str,
                                                          indent=1).encode())

    def _file(self, i: int) -> Path:
        return self.dir / f"task-{i:06d}.pkl"

    @staticmethod
    def _write(path: Path, blob: bytes) -> None:
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            f.write(blob)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)  # atomic: a file is either whole or absent

    def load(self, n_tasks: int) -> dict:
        """Results already finished, by task index (an unreadable file is flown again)."""
        done = {}
        for i in range(n_tasks):
            try:
                done[i] = pickle.loads(self._file(i).read_bytes())
            except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError):
                continue
        self.resumed_items = sum(len(r) for r in done.values())
        return done

    def save(self, i: int, result) -> None:
        self._write(self._file(i), pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))

    def remove(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


def _worker_init() -> None:
    """Pool workers leave Ctrl-C to the parent (a terminal sends SIGINT to the whole process group),
    which stops them and keeps the checkpoint consistent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def show_progress(requested: bool = True) -> bool:
    """Progress bars only for a person: on a terminal (stderr a TTY), never in logs, pipes or CI."""
    import sys

    return bool(requested) and sys.stderr.isatty()


def run_tasks(tasks, workers, scheduler, progress, total, fn, desc="tasks", checkpoint: Checkpoint | None = None,
              on_result=None):
    """Run `fn(task) -> list` over `tasks` on a local process pool (`workers` > 1), in-process
    (`workers` ≤ 1) or on a Dask distributed cluster (`scheduler` address); a tqdm bar counts the
    items of the returned lists up to `total`. `fn` must be a module-level function (picklable).
    Results come back in task order. With a `checkpoint`, finished tasks are skipped and each new
    result is saved as it arrives; an interrupt (KeyboardInterrupt) stops the workers and raises
    `BuildInterrupted` with one line saying what is kept. With `on_result(i, result)`, each result is
    handed over as it arrives (in any order) and not kept: None is returned (a campaign's rows)."""
    from tqdm import tqdm

    results = [None] * len(tasks)
    if checkpoint is not None:
        for i, r in checkpoint.load(len(tasks)).items():
            results[i] = r
    todo = [i for i in range(len(tasks)) if results[i] is None]
    bar = tqdm(total=total, initial=sum(len(r) for r in results if r is not None), desc=desc, unit="cell",
               disable=not progress, dynamic_ncols=True)
    n_done = [sum(len(r) for r in results if r is not None)]  # items finished (a result handed on is not kept)

    def finished(i, r):
        if on_result is not None:
            on_result(i, r)
        else:
            results[i] = r
        if checkpoint is not None:
            checkpoint.save(i, r)
        n_done[0] += len(r)
        bar.update(len(r))

    pool = None
    try:
        if scheduler:
            from distributed import Client, as_completed

            with Client(scheduler) as client:
                futs = {client.submit(fn, tasks[i], pure=False): i for i in todo}
                for f in as_completed(list(futs)):
                    finished(futs[f], f.result())
        elif workers <= 1:
            for i in todo:
                finished(i, fn(tasks[i]))
        elif todo:
            for k, v in ONE_THREAD.items():  # one solver thread per worker process (inherited at spawn)
                os.environ.setdefault(k, v)
            import multiprocessing as mp

            pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                          initializer=_worker_init)
            futs = {pool.submit(fn, tasks[i]): i for i in todo}
            for f in cf.as_completed(futs):
                finished(futs[f], f.result())
            pool.shutdown(wait=True)
            pool = None
    except KeyboardInterrupt:
        if pool is not None:
            procs = list(getattr(pool, "_processes", {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                p.terminate()
        bar.close()
        where = (f"the finished ones are checkpointed in {checkpoint.dir}: run the same command with --resume "
                 f"to continue") if checkpoint is not None else "nothing was kept"
        raise BuildInterrupted(f"interrupted after {n_done[0]} of {total} cells; {where}") from None
    bar.close()
    return None if on_result is not None else results
