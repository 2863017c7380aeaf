"""Where the protocol's shards of work run: this process, a local process pool, or Ray actors.

`aed collect` (expert episodes) and `aed rollout` (policy episodes) both cut their work into
independent *jobs* whose results do not depend on where or in which order they run. Each
worker keeps one *runner* (its envs and models: `gym.make` and loading a checkpoint cost
seconds) and feeds it jobs. A runner is made by a picklable factory, e.g.
`functools.partial(ExpertRunner, cfg)`, so the same factory serves every executor:

- inline (`workers=1`): in this process, optionally reusing a runner the caller already has;
- local: a pool of fresh (spawned) interpreters, no forked renderer state;
- ray: Ray actors on a cluster (the `ray` extra); outputs must go to a shared filesystem.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal, Protocol

from aed_eval.logs import setup_logging

logger = logging.getLogger(__name__)

Executor = Literal["local", "ray"]


class Runner(Protocol):
    """Runs jobs in one worker; `tick(n)` reports n finished episodes to the progress bar."""

    def run(self, job: Any, tick: Callable[[int], None] | None = None) -> Any: ...

    def close(self) -> None: ...


def execute(
    jobs: Sequence[Any],
    make_runner: Callable[[], Runner],
    *,
    on_done: Callable[[Any], None],
    workers: int = 1,
    executor: Executor = "local",
    ray_address: str | None = None,
    progress: Any = None,
    runner: Runner | None = None,
) -> None:
    """Run every job once and hand each result to `on_done` (in completion order).

    Args:
        jobs: independent units of work (picklable for the pool and Ray).
        make_runner: picklable factory of a worker's runner.
        on_done: called in this process with each result, as it arrives.
        workers: parallel workers; 1 runs inline.
        executor: "local" (process pool) or "ray".
        ray_address: Ray cluster address (None: start or join a local Ray).
        progress: a tqdm-like bar (`update(n)`) or None.
        runner: inline only: an existing runner to reuse (not closed here).
    """
    if workers < 1:
        raise ValueError(f"workers={workers}: must be >= 1")
    if executor not in ("local", "ray"):
        raise ValueError(f"executor={executor!r}: local or ray")
    if not jobs:
        return
    tick = progress.update if progress is not None else None
    if executor == "ray":
        _execute_ray(jobs, make_runner, on_done, workers, ray_address, tick)
    elif workers == 1:
        _execute_inline(jobs, make_runner, on_done, tick, runner)
    else:
        _execute_pool(jobs, make_runner, on_done, workers, tick)


def _execute_inline(
    jobs: Sequence[Any],
    make_runner: Callable[[], Runner],
    on_done: Callable[[Any], None],
    tick: Callable[[int], None] | None,
    runner: Runner | None,
) -> None:
    own = runner is None
    runner = runner or make_runner()
    try:
        for job in jobs:
            on_done(runner.run(job, tick))
    finally:
        if own:
            runner.close()


def worker_threads(workers: int) -> int:
    """Threads per worker process: `AED_WORKER_THREADS` if set (0: each library's default, every
    core), else the worker's share of the cores."""
    value = os.environ.get("AED_WORKER_THREADS")
    if value is not None:
        if not value.isdigit():
            raise ValueError(
                f"AED_WORKER_THREADS={value!r}: a number of threads, "
                "or 0 for the libraries' defaults"
            )
        return int(value)
    return max(1, (os.cpu_count() or 1) // workers)


def share_cores(threads: int) -> None:
    """Let this process's torch and lavapipe (SAPIEN's CPU renderer) use `threads` threads.

    Each library sizes its pool to every core by default, so N workers would run N times as
    many threads as there are cores, and thrash. 0 leaves the defaults.
    """
    if threads < 1:
        return
    import torch

    os.environ["LP_NUM_THREADS"] = str(threads)  # read when the renderer starts
    torch.set_num_threads(threads)


# Local process pool: each worker process keeps its own runner.
_WORKER: dict[str, Any] = {}


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int, poll_s: float = 1.0) -> None:
    """End this worker when `parent` ends, so that no orphan keeps committing shards after its
    run was killed (and the user restarted it).

    Linux: the kernel sends SIGKILL on the parent's death (prctl PR_SET_PDEATHSIG). Everywhere,
    a daemon thread also checks the parent every `poll_s` seconds (it covers other systems, and
    a parent thread, not process, that ended: the prctl signal follows the thread).
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
                logger.debug("prctl(PR_SET_PDEATHSIG) failed: errno %d", ctypes.get_errno())
        except (OSError, AttributeError) as e:
            logger.debug("no prctl: %s", e)
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="aed-parent-watch", daemon=True).start()


def _init_worker(
    make_runner: Callable[[], Runner], ticks: Any, log_level: int, threads: int, parent: int
) -> None:
    die_with_parent(parent)
    setup_logging(log_level)
    share_cores(threads)
    _WORKER["ticks"] = ticks
    try:
        _WORKER["runner"] = make_runner()
    except Exception as e:  # an initializer's error breaks the pool and is lost: keep it
        _WORKER["error"] = e


def _run_in_worker(job: Any) -> Any:
    if "error" in _WORKER:  # the runner failed to start: the parent gets its error
        raise _WORKER["error"]
    ticks = _WORKER["ticks"]
    return _WORKER["runner"].run(job, ticks.put)


def _execute_pool(
    jobs: Sequence[Any],
    make_runner: Callable[[], Runner],
    on_done: Callable[[Any], None],
    workers: int,
    tick: Callable[[int], None] | None,
) -> None:
    import multiprocessing as mp
    import queue as queue_lib
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = mp.get_context("spawn")  # fresh interpreters: no forked renderer state
    ticks = ctx.Queue()
    level = logging.getLogger().getEffectiveLevel()
    workers = min(workers, len(jobs))
    threads = worker_threads(workers)
    with ProcessPoolExecutor(
        workers,
        mp_context=ctx,
        initializer=_init_worker,
        initargs=(make_runner, ticks, level, threads, os.getpid()),
    ) as pool:
        pending = {pool.submit(_run_in_worker, job) for job in jobs}
        try:
            while pending:
                finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                while True:
                    try:
                        n = ticks.get_nowait()
                    except queue_lib.Empty:
                        break
                    if tick is not None:
                        tick(n)
                for future in finished:
                    on_done(future.result())
        except BaseException:
            for future in pending:
                future.cancel()
            raise


def _execute_ray(
    jobs: Sequence[Any],
    make_runner: Callable[[], Runner],
    on_done: Callable[[Any], None],
    workers: int,
    ray_address: str | None,
    tick: Callable[[int], None] | None,
) -> None:
    try:
        import ray
        from ray.util import ActorPool
    except ImportError as e:
        raise ImportError("executor='ray' needs Ray: pip install 'aed-toolkit[ray]'") from e

    if not ray.is_initialized():
        ray.init(address=ray_address)

    @ray.remote
    class RayRunner:
        def __init__(self, make_runner: Callable[[], Runner]):
            self.runner = make_runner()

        def run(self, job: Any) -> Any:
            return self.runner.run(job)

    actors = [RayRunner.remote(make_runner) for _ in range(min(workers, len(jobs)))]
    pool = ActorPool(actors)
    for result in pool.map_unordered(lambda actor, job: actor.run.remote(job), list(jobs)):
        if tick is not None:
            tick(getattr(result, "episodes", 1))
        on_done(result)
