"""Run a picklable function over a list of jobs: on a local process pool or on Dask.

Every job's outcome comes back as an :class:`Outcome` (value, or the one-line error of a
:class:`~mocap_calib.errors.CalibrationError`, or "internal error: ..."), in completion order, so
one failing job never stops the others. The function must be importable by the worker (a
module-level function; with Dask, cloudpickle also ships functions defined in a script).

    with make_engine("local", workers=2) as engine:
        for outcome in engine.run(study_case, cases):
            ...

or, for a study that just wants the values back in order: ``map_jobs(fn, jobs, workers=2)``.
"""

from __future__ import annotations

import importlib.util
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from mocap_calib.errors import CalibrationError, InputError, Interrupted

ENGINES = ("local", "dask")


@dataclass
class Outcome:
    """What one job gave: ``value`` when ``ok``, else ``error`` (one line)."""

    index: int
    ok: bool
    value: Any = None
    error: str = ""
    seconds: float = 0.0


def one_line(text: str) -> str:
    return " ".join(str(text).split())


def guarded_call(fn: Callable[[Any], Any], job: Any) -> tuple[bool, Any, str, float]:
    """Call ``fn(job)`` in the worker; expected failures become a one-line error, not a raise
    (``KeyboardInterrupt`` still propagates)."""
    t0 = time.perf_counter()
    try:
        value = fn(job)
        return True, value, "", time.perf_counter() - t0
    except Interrupted:
        raise
    except CalibrationError as err:
        msg = one_line(str(err))
    except MemoryError:
        msg = "out of memory; calibrate a shorter part of the session (start/end)"
    except Exception as err:  # a bug: keep the batch going, name it
        msg = f"internal error: {type(err).__name__}: {one_line(str(err))}"
    return False, None, msg, time.perf_counter() - t0


class Engine:
    """Base: a context manager whose :meth:`run` yields outcomes as jobs finish."""

    name = "engine"
    workers = 1

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def run(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[Outcome]:
        raise NotImplementedError


_started: Any = None  # in a local worker: where it reports the job it starts
#: How often a worker's watchdog looks whether its parent is still there (s).
WATCHDOG_S = 0.5
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _exit_now() -> None:
    os._exit(1)  # no clean-up: the parent that would collect the result is gone


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(WATCHDOG_S)
        if os.getppid() != parent:
            _exit_now()


def die_with_parent(parent: int) -> None:
    """End this process when ``parent`` ends, however it ends (``kill -9`` included): on Linux
    the kernel sends SIGKILL at once (``PR_SET_PDEATHSIG``); everywhere a daemon thread also
    checks every :data:`WATCHDOG_S` s that the parent is still ours (a process whose parent
    died is given another). A parent already gone ends this one at once."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no prctl (another C library): the watchdog alone
    if os.getppid() != parent:
        _exit_now()
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True,
                     name="mocap-calib-parent-watchdog").start()


def _init_worker(started: Any, chunk_threads: int = 1, parent: int | None = None) -> None:
    global _started
    if parent is not None:
        die_with_parent(parent)
    _started = started
    # The pool already runs one session per core: the window engine's own threads would only
    # contend with the other workers.
    from mocap_calib.core.threads import set_chunk_threads

    set_chunk_threads(chunk_threads)
    # Ctrl-C is handled by the parent, which stops the workers itself; a worker interrupted
    # mid-job would only add tracebacks.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _one_thread_call(fn: Callable[[Any], Any], job: Any) -> tuple[bool, Any, str, float]:
    from mocap_calib.core.threads import set_chunk_threads

    set_chunk_threads(1)
    return guarded_call(fn, job)


def _tracked_call(fn: Callable[[Any], Any], job: Any, index: int) -> tuple[bool, Any, str, float]:
    _started.put(index)  # a SimpleQueue: written before the job runs, even if it then crashes
    return guarded_call(fn, job)


class LocalEngine(Engine):
    """A pool of ``workers`` processes on this machine (spawned: no state leaks from the
    parent, and GTSAM's threads are never forked).

    A job that kills its worker (a crash, the out-of-memory killer) breaks the whole pool. The
    jobs that had started then are run again one at a time, alone, so the one that crashes is
    named and the others finish; the jobs that had not started go to a fresh pool.
    """

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self._ctx = multiprocessing.get_context("spawn")
        self._pool: ProcessPoolExecutor | None = None
        self._started: Any = None

    def _new_pool(self, workers: int | None = None) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(workers or self.workers, mp_context=self._ctx,
                                   initializer=_init_worker,
                                   initargs=(self._started,
                                             max(1, (os.cpu_count() or 1)
                                                 // (workers or self.workers)),
                                             os.getpid()))

    def __enter__(self) -> LocalEngine:
        self._started = self._ctx.SimpleQueue()
        self._pool = self._new_pool()
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self._pool is None:
            return
        if exc_type is not None:  # Ctrl-C or an error: stop running jobs at once
            self._terminate()
        else:
            self._pool.shutdown(wait=True)
        self._pool = None

    def _terminate(self) -> None:
        assert self._pool is not None
        # No public API stops running tasks; the pool's own process table is the way.
        for proc in list(getattr(self._pool, "_processes", {}).values()):
            if proc.is_alive():
                proc.terminate()
        self._pool.shutdown(wait=False, cancel_futures=True)

    def _drain(self, started: set[int]) -> None:
        while not self._started.empty():
            started.add(self._started.get())

    def run(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[Outcome]:
        if self._pool is None:
            raise RuntimeError("use the engine in a 'with' block")
        todo = list(range(len(jobs)))
        while todo:
            suspects, todo = yield from self._run_pool(fn, jobs, todo)
            for i in suspects:
                yield self._alone(fn, jobs[i], i)

    def _run_pool(self, fn: Callable[[Any], Any], jobs: Sequence[Any], todo: list[int]
                  ) -> Generator[Outcome, None, tuple[list[int], list[int]]]:
        """Run ``todo`` on the pool; on a break return (started, not started) of the rest."""
        assert self._pool is not None
        pending = {self._pool.submit(_tracked_call, fn, jobs[i], i): i for i in todo}
        started: set[int] = set()
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            self._drain(started)  # also keeps the start reports from filling their pipe
            lost: list[int] = []
            for fut in done:
                i = pending.pop(fut)
                try:
                    ok, value, err, secs = fut.result()
                except BrokenProcessPool:
                    lost.append(i)
                    continue
                yield Outcome(i, ok, value, err, secs)
            if lost:
                lost += pending.values()
                self._drain(started)
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = self._new_pool()
                lost.sort()
                return [i for i in lost if i in started], [i for i in lost if i not in started]
        return [], []

    def _alone(self, fn: Callable[[Any], Any], job: Any, i: int) -> Outcome:
        pool = self._new_pool(1)
        try:
            ok, value, err, secs = pool.submit(_tracked_call, fn, job, i).result()
            return Outcome(i, ok, value, err, secs)
        except BrokenProcessPool:
            return Outcome(i, False, error="its worker process died (a crash or out of memory); "
                           "run this session alone with 'mocap-calib calibrate' to see why")
        finally:
            pool.shutdown(wait=True)


class DaskEngine(Engine):
    """``dask.distributed``: a ``LocalCluster`` of ``workers`` single-threaded processes, or the
    cluster whose scheduler is at ``scheduler`` (the workers must see the input files)."""

    name = "dask"

    def __init__(self, workers: int | None = None, scheduler: str | None = None) -> None:
        self.scheduler = scheduler
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self._client: Any = None
        self._cluster: Any = None

    def __enter__(self) -> DaskEngine:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise InputError("--engine dask needs Dask: pip install 'mocap-calib[cluster]'"
                             ) from None
        if self.scheduler:
            try:
                self._client = Client(self.scheduler, timeout="20s")
            except (OSError, TimeoutError, ValueError) as err:
                why = one_line(str(err))
                raise InputError(f"--scheduler {self.scheduler}: cannot connect ({why}); start "
                                 "the scheduler or check the address") from None
            self.workers = max(1, sum(self._client.nthreads().values()))
        else:
            self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                         processes=True, dashboard_address=None,
                                         silence_logs=logging.ERROR)
            self._client = Client(self._cluster)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._client = self._cluster = None

    def run(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[Outcome]:
        from distributed import as_completed

        if self._client is None:
            raise RuntimeError("use the engine in a 'with' block")
        # A LocalCluster runs a worker per core: each evaluates its windows on one thread.
        call = _one_thread_call if self._cluster is not None else guarded_call
        futures = [self._client.submit(call, fn, job, pure=False) for job in jobs]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                i = index[fut.key]
                try:
                    ok, value, err, secs = fut.result()
                except Interrupted:
                    raise
                except Exception as exc:  # KilledWorker, a lost connection...
                    yield Outcome(i, False, error=f"the Dask worker failed: {type(exc).__name__}: "
                                  f"{one_line(str(exc))}")
                    continue
                yield Outcome(i, ok, value, err, secs)
        finally:
            self._client.cancel([f for f in futures if not f.done()])


def check_scheduler_address(address: str) -> None:
    """A scheduler address Dask can connect to, checked before any work (without connecting):
    ``tcp://HOST:PORT`` (or ``HOST:PORT``, or another of Dask's protocols).

    Raises:
        InputError: naming the address, the problem and the form.
    """
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        if scheme in ("tcp", "tls", "ws", "wss"):
            parse_host_port(location)
    except ValueError as err:
        raise InputError(f"--scheduler {address}: {one_line(str(err))}; give the address as "
                         "tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786") from None


def make_engine(name: str = "local", workers: int | None = None,
                scheduler: str | None = None) -> Engine:
    """``local`` (default) or ``dask``; raises :class:`InputError` for anything else."""
    if workers is not None and workers < 1:
        raise InputError(f"--workers {workers}: give 1 or more")
    if name == "local":
        if scheduler:
            raise InputError("--scheduler needs --engine dask")
        return LocalEngine(workers)
    if name == "dask":
        if importlib.util.find_spec("distributed") is None:
            raise InputError("--engine dask needs Dask: pip install 'mocap-calib[cluster]'")
        if scheduler and workers is not None:
            raise InputError("--workers with --scheduler: the cluster has its own workers; "
                             "drop --workers")
        if scheduler:
            check_scheduler_address(scheduler)
        return DaskEngine(workers, scheduler)
    raise InputError(f"unknown --engine '{name}'; choose {' or '.join(ENGINES)}")


def map_jobs(fn: Callable[[Any], Any], jobs: Sequence[Any], engine: str = "local",
             workers: int | None = None, scheduler: str | None = None,
             on_outcome: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """Run ``fn`` over ``jobs``; the outcomes in job order."""
    out: list[Outcome | None] = [None] * len(jobs)
    with make_engine(engine, workers, scheduler) as eng:
        for o in eng.run(fn, jobs):
            out[o.index] = o
            if on_outcome is not None:
                on_outcome(o)
    return [o for o in out if o is not None]
