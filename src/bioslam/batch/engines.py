"""Where the runs execute: Ray (a local instance or an existing cluster) or a local process pool.

Both engines take the same tasks and yield the same :class:`~bioslam.batch.task.Outcome` as
runs finish, in whatever order they finish. Ray is imported only here, only when chosen, so
the rest of the package works without it.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol

from bioslam.batch.task import Files, Outcome, Task, run_task

ENGINES = ("ray", "process")
#: A worker lost (killed, out of memory, a crash in compiled code) costs its run another try,
#: at most this many in all; a pool that breaks is restarted for its unfinished runs.
MAX_ATTEMPTS = 2


def ray_available() -> bool:
    """Whether the optional ``ray`` extra is installed (without importing it)."""
    import importlib.util

    return importlib.util.find_spec("ray") is not None


def default_engine() -> str:
    return "ray" if ray_available() else "process"


class Engine(Protocol):
    """Runs tasks and yields their outcomes as they finish."""

    workers: int

    def run(self, tasks: Sequence[Task], shipped: dict[str, Files] | None) -> Iterator[Outcome]:
        """``shipped`` maps a log name to its bytes when data is shipped."""
        ...

    def stop(self) -> None:
        """End every run under way now and release the workers (Ctrl-C)."""
        ...


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the batch, which stops them itself; otherwise each run would
    catch it, write a partial result and report it as a finished run."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _lost(task: Task, reason: str) -> Outcome:
    return Outcome(task.key, "failed", error=reason)


class ProcessEngine:
    """A local pool of ``workers`` processes started with ``spawn`` (no state inherited from the
    batch's process, the same start on every platform)."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"--workers must be at least 1, got {workers}")
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        self._pool = ProcessPoolExecutor(
            self.workers, mp_context=multiprocessing.get_context("spawn"),
            initializer=_ignore_sigint,
        )
        return self._pool

    def run(self, tasks: Sequence[Task], shipped: dict[str, Files] | None) -> Iterator[Outcome]:
        attempts = {task.key: 0 for task in tasks}
        queue = list(tasks)
        while queue:
            pool = self._new_pool()
            futures: dict[Future[Outcome], Task] = {
                pool.submit(run_task, task, shipped[task.log_name] if shipped else None): task
                for task in queue
            }
            queue = []
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for future in done:
                    task = futures.pop(future)
                    try:
                        yield future.result()
                    except BrokenProcessPool:
                        attempts[task.key] += 1
                        if attempts[task.key] < MAX_ATTEMPTS:
                            queue.append(task)
                        else:
                            yield _lost(task, "worker process died (killed, out of memory or "
                                        "crashed) while this run was under way or queued")
            pool.shutdown(wait=True)
        self._pool = None

    def stop(self) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        # ProcessPoolExecutor has no way to end running calls before Python 3.14
        # (terminate_workers); its worker processes are terminated directly.
        for process in list(getattr(pool, "_processes", {}).values()):
            process.terminate()
        pool.shutdown(wait=True, cancel_futures=True)


class RayEngine:
    """Ray tasks of one CPU each, at most ``workers`` under way at a time.

    Without ``address`` (nor ``RAY_ADDRESS`` in the environment) a local Ray instance with
    ``workers`` CPUs is started and shut down with the batch; with one the batch joins that
    cluster, and ``workers`` defaults to the cluster's CPU count.
    """

    def __init__(self, workers: int | None, address: str | None = None) -> None:
        import ray

        self._ray = ray
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        options: dict[str, Any] = {
            "include_dashboard": False, "log_to_driver": False, "logging_level": logging.WARNING,
        }
        if self.address is None:
            self.workers = workers or os.cpu_count() or 1
            # "local": a new instance of our own even when another one runs on this machine
            ray.init(address="local", num_cpus=self.workers, **options)
        else:
            ray.init(address=self.address, **options)
            self.workers = workers or int(ray.cluster_resources().get("CPU", 1))
        if self.workers < 1:
            raise ValueError(f"--workers must be at least 1, got {self.workers}")
        # run_task turns the run's own errors into outcomes; what Ray retries is a worker lost
        # (killed by Ray's memory monitor on a crowded node, a crash), like the pool does
        self._remote = ray.remote(num_cpus=1, max_retries=MAX_ATTEMPTS - 1)(run_task)
        self._pending: dict[Any, Task] = {}

    def run(self, tasks: Sequence[Task], shipped: dict[str, Files] | None) -> Iterator[Outcome]:
        ray = self._ray
        # Each log goes into the object store once, however many runs read it.
        refs = {name: ray.put(files) for name, files in (shipped or {}).items()}
        queue = list(reversed(tasks))
        while queue or self._pending:
            while queue and len(self._pending) < self.workers:
                task = queue.pop()
                data = refs[task.log_name] if shipped else None
                self._pending[self._remote.remote(task, data)] = task
            ready, _ = ray.wait(list(self._pending), num_returns=1)
            task = self._pending.pop(ready[0])
            try:
                yield ray.get(ready[0])
            except ray.exceptions.RayError as exc:
                yield _lost(task, f"{type(exc).__name__}: {str(exc).strip().splitlines()[0]}")

    def stop(self) -> None:
        for ref in list(self._pending):
            self._ray.cancel(ref, force=True)
        self._pending.clear()
        self.shutdown()

    def shutdown(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()


def make_engine(name: str, workers: int | None, address: str | None = None) -> Engine:
    """The engine ``name``; Ray without the extra installed is a clear error."""
    if name == "process":
        if address:
            raise ValueError("--address is a Ray cluster address; it needs --engine ray")
        return ProcessEngine(workers or os.cpu_count() or 1)
    if name == "ray":
        if not ray_available():
            raise RuntimeError("the Ray engine needs Ray: pip install 'bioslam[ray]' "
                               "(or use --engine process)")
        return RayEngine(workers, address)
    raise ValueError(f"unknown engine {name!r}; choose one of {', '.join(ENGINES)}")


def close_engine(engine: Engine) -> None:
    """Release what the engine holds once the batch is over."""
    shutdown: Callable[[], None] | None = getattr(engine, "shutdown", None)
    if shutdown is not None:
        shutdown()
