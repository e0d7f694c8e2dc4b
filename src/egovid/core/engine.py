"""Run many independent tasks: in this process, on a local pool of worker processes, or on a Dask
cluster.

This is the one place egovid talks to Dask (``dask.distributed``); the dashcam ingest and the voeval
grid both go through it, so a local run and a cluster run share one code path.

* :func:`scheduler_address` resolves ``--scheduler`` (else Dask's own ``DASK_SCHEDULER_ADDRESS``).
* :func:`open_client` yields a Dask client: connected to that scheduler, or to a throw-away
  ``LocalCluster`` of worker processes bound to 127.0.0.1, or ``None`` for in-process work.
* :func:`run_tasks` runs ``fn(item)`` for every item and yields a :class:`TaskOutcome` per task as
  tasks finish.
* :func:`spawn_cluster` starts ``dask scheduler`` and ``dask worker`` as separate processes on
  127.0.0.1 (what ``--scheduler`` talks to on a real cluster), for the tests and benchmarks that
  try the cluster path on one machine.

Dask pitfalls handled here: a ``dask worker`` (its nanny) starts worker processes with
``MALLOC_TRIM_THRESHOLD_=65536``, which makes glibc return every freed video frame to the operating
system and fetch it again (an ECC voeval cell: 6x the page faults, 1.8x the CPU time); every task
undoes that first (:func:`steady_malloc`). ``submit`` defaults to ``pure=True`` (identical arguments would run once;
we always pass ``pure=False`` and a unique key); a task that *raises* is retried ``retries`` times; a
task whose worker *dies* (killed, out of memory) is rescheduled by the scheduler on another worker
(up to ``distributed.scheduler.allowed-failures`` times, then it fails with ``KilledWorker``). So a
task may run more than once: tasks must be idempotent (write atomically, commit once). Nothing here
goes through Dask's *default* client (``as_completed``, ``wait``): that is the last Client created in
the process, possibly someone else's, already closed.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import os
import queue
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from egovid.core.errors import EgovidError

SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
_POLL_S = 5.0  # the longest a cluster run waits before it looks at every task's state again


@dataclass(frozen=True)
class EngineConfig:
    """Where tasks run.

    ``scheduler``: address of a running Dask scheduler (``tcp://HOST:8786``), or ``None`` for this
    machine. ``workers``: local worker processes when there is no scheduler (1 = run in this
    process, no Dask at all). ``retries``: extra attempts for a task that raised an exception.
    """

    scheduler: str | None = None
    workers: int = 1
    retries: int = 1

    def __post_init__(self) -> None:
        if self.workers < 1 or self.workers > 512:
            raise EgovidError(f"--workers {self.workers} is out of range", "use 1 to 512 worker processes")
        if self.retries < 0 or self.retries > 10:
            raise EgovidError(f"retries {self.retries} is out of range", "use 0 to 10")

    @property
    def in_process(self) -> bool:
        """True when tasks run one after another in this process."""
        return self.scheduler is None and self.workers == 1


@dataclass
class TaskOutcome:
    """The end of one task: ``value`` when it returned, ``error`` when it failed for good."""

    key: str
    item: Any
    value: Any = None
    error: BaseException | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def scheduler_address(option: str | None) -> str | None:
    """The scheduler to use: ``option`` (a ``--scheduler`` value), else ``$DASK_SCHEDULER_ADDRESS``
    (Dask's standard variable), else ``None`` (this machine)."""
    address = option or os.environ.get(SCHEDULER_ENV) or None
    if address is not None and "://" not in address and ":" not in address:
        raise EgovidError(
            f"scheduler address {address!r} has no port",
            "write it as tcp://HOST:8786 (the address `dask scheduler` prints)",
        )
    return address


@contextlib.contextmanager
def open_client(config: EngineConfig, *, connect_timeout: float = 30.0) -> Iterator[Any]:
    """Yield a ``distributed.Client`` for ``config``, or ``None`` when tasks run in this process.

    Without a scheduler a ``LocalCluster`` of ``config.workers`` single-threaded worker processes is
    started on 127.0.0.1 (no dashboard) and closed afterwards. An unreachable scheduler gives an
    :class:`EgovidError`.
    """
    if config.in_process:
        yield None
        return
    from distributed import Client, LocalCluster

    if config.scheduler is not None:
        try:
            client = Client(config.scheduler, timeout=connect_timeout)
        except (OSError, TimeoutError) as exc:
            raise EgovidError(
                f"cannot reach the Dask scheduler at {config.scheduler} ({type(exc).__name__})",
                "start one with `dask scheduler` and workers with `dask worker ADDRESS`, or drop --scheduler",
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    cluster = LocalCluster(
        n_workers=config.workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",  # its HTTP server (health, metrics) on loopback only
        worker_dashboard_address="127.0.0.1:0",
        silence_logs=40,  # logging.ERROR
    )
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def run_tasks(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    config: EngineConfig,
    keys: Sequence[str] | None = None,
    name: str = "task",
    client: Any = None,
    after: Mapping[str, Sequence[str]] | None = None,
) -> Iterator[TaskOutcome]:
    """Run ``fn(item)`` for every item; yield a :class:`TaskOutcome` per task as tasks finish.

    ``fn`` must be importable by the workers (a module-level function) and idempotent (it may run
    again after a worker died). ``keys`` names the tasks (default: their index); task keys on the
    cluster are ``NAME-KEY-<random>`` so that two runs never collide. ``client`` reuses an open
    client (from :func:`open_client`); otherwise one is opened for this call. A task that raises is
    retried ``config.retries`` times, then reported with its ``error``; other tasks carry on.
    ``after`` maps a key to the keys whose tasks must have finished (well or not) before it starts:
    a task is handed to the cluster only then, so waiting never holds a worker.
    """
    items = list(items)
    keys = [str(k) for k in (keys if keys is not None else range(len(items)))]
    if len(keys) != len(items):
        raise ValueError("one key per item")
    waits = {k: {str(d) for d in (after or {}).get(k, ())} & set(keys) for k in keys}
    if config.in_process and client is None:
        yield from _run_in_order(fn, keys, items, waits, config.retries)
        return
    with contextlib.ExitStack() as stack:
        if client is None:
            client = stack.enter_context(open_client(config))
        yield from _ClusterRun(client, fn, dict(zip(keys, items, strict=True)), waits, name, config.retries).outcomes()


def _run_in_order(
    fn: Callable[[Any], Any], keys: list[str], items: list, waits: dict[str, set[str]], retries: int
) -> Iterator[TaskOutcome]:
    """The tasks in this process, one after the other, each once the tasks it waits for are done."""
    done: set[str] = set()
    todo = list(zip(keys, items, strict=True))
    while todo:
        i = next((i for i, (k, _) in enumerate(todo) if waits[k] <= done), 0)  # 0: a cycle, break it
        key, item = todo.pop(i)
        yield _run_here(fn, key, item, retries)
        done.add(key)


class _ClusterRun:
    """The tasks of one :func:`run_tasks` call on a Dask client: each handed to the cluster once the
    tasks it waits for have finished, reported as it finishes."""

    def __init__(
        self, client: Any, fn: Callable[[Any], Any], pending: dict, waits: dict[str, set[str]], name: str, retries: int
    ) -> None:
        self.client, self.fn, self.pending, self.waits = client, fn, pending, waits
        self.name, self.retries = name, retries
        self.token = uuid.uuid4().hex[:8]
        self.futures: dict = {}
        self.finished: set[str] = set()
        self.running: list = []  # submitted, not yet reported
        self.wakeups: queue.SimpleQueue = queue.SimpleQueue()

    def _submit_ready(self) -> list:
        ready = [k for k in self.pending if self.waits[k] <= self.finished]
        if not ready and self.pending and not self.running:
            ready = [next(iter(self.pending))]  # a cycle in ``after`` (nothing else in flight): break it
        out = []
        for key in ready:
            item = self.pending.pop(key)
            fut = self.client.submit(
                functools.partial(_on_worker, self.fn),
                item,
                key=f"{self.name}-{key}-{self.token}",
                pure=False,
                retries=self.retries,
            )
            self.futures[fut] = (key, item)
            out.append(fut)
        return out

    # Not ``distributed.as_completed`` nor ``distributed.wait``: both work through Dask's
    # *default* client (the last Client created in this process), which need not be ``client``.
    # as_completed tracked our futures on that client's event loop; once that other client had
    # closed (a caller's, a test's), completions were never seen and the run hung. A future's
    # done-callback runs on its own client's loop; it only wakes this loop, which then looks at
    # every running future's state (again at least every _POLL_S seconds, a missed wake-up
    # costs no more than that).
    def _track(self, new: list) -> None:
        for fut in new:
            self.running.append(fut)
            fut.add_done_callback(self.wakeups.put)

    def outcomes(self) -> Iterator[TaskOutcome]:
        """Every task's outcome as it finishes; unfinished tasks are cancelled when left early."""
        self._track(self._submit_ready())
        try:
            while self.running:
                with contextlib.suppress(queue.Empty):
                    self.wakeups.get(timeout=_POLL_S)
                for fut in [f for f in self.running if f.done()]:
                    self.running.remove(fut)
                    key, item = self.futures[fut]
                    try:
                        outcome = TaskOutcome(key, item, value=fut.result())
                    except Exception as exc:  # the task failed for good, its worker kept dying, cancelled
                        outcome = TaskOutcome(key, item, error=exc)
                    self.finished.add(key)
                    fut.release()
                    self._track(self._submit_ready())  # before yielding: they run while the caller looks
                    yield outcome
        finally:
            for fut in self.futures:
                if not fut.done():
                    fut.cancel()


#: glibc mallopt parameters, and the values a task sets (bytes): blocks below 32 MiB come from the
#: heap and up to 64 MiB of freed heap is kept, glibc's own steady state for programs that allocate
#: many large frames.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_TRIM_BYTES, _MMAP_BYTES = 64 << 20, 32 << 20


def steady_malloc() -> bool:
    """Undo the Dask nanny's ``MALLOC_TRIM_THRESHOLD_=65536`` (its default ``pre-spawn-environ``)
    in this process and for the processes it starts (odometers, ffmpeg). Returns False where the C
    library has no ``mallopt`` (not glibc)."""
    import ctypes
    import ctypes.util

    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        return bool(libc.mallopt(_M_TRIM_THRESHOLD, _TRIM_BYTES)) and bool(libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_BYTES))
    except (OSError, AttributeError):
        return False


def _on_worker(fn: Callable[[Any], Any], item: Any) -> Any:
    """What a Dask worker runs for a task: :func:`steady_malloc`, then ``fn(item)``."""
    steady_malloc()
    return fn(item)


def _run_here(fn: Callable[[Any], Any], key: str, item: Any, retries: int) -> TaskOutcome:
    error: BaseException | None = None
    for _attempt in itertools.count():
        try:
            return TaskOutcome(key, item, value=fn(item))
        except EgovidError as exc:  # a user error does not get better by trying again
            return TaskOutcome(key, item, error=exc)
        except Exception as exc:
            error = exc
            if _attempt >= retries:
                break
    return TaskOutcome(key, item, error=error)


@contextlib.contextmanager
def spawn_cluster(
    folder: Path,
    *,
    workers: int = 2,
    env: Mapping[str, str] | None = None,
    on_spawn: Callable[[subprocess.Popen], None] | None = None,
    timeout: float = 180.0,
) -> Iterator[str]:
    """Start ``dask scheduler`` and ``dask worker --nworkers WORKERS --nthreads 1`` as separate
    processes (each in its own process group) on 127.0.0.1 with free ports and no dashboard; yield
    the scheduler address once all workers have joined; stop them (SIGTERM, then SIGKILL after
    30 s) on exit.

    ``folder`` holds the scheduler file, the workers' local directory and the two logs
    (``scheduler.log``, ``workers.log``). ``env`` is the processes' environment (default: this
    one's). ``on_spawn`` is called with each started process (e.g. to kill it if the caller dies).
    A scheduler or workers not up within ``timeout`` seconds raise :class:`TimeoutError`.
    """
    folder.mkdir(parents=True, exist_ok=True)
    sched_file = folder / "scheduler.json"
    sched_file.unlink(missing_ok=True)
    dask = str(Path(sys.executable).parent / "dask")
    local = ["--host", "127.0.0.1", "--no-dashboard"]
    procs: list[subprocess.Popen] = []

    def spawn(args: list[str], log: str) -> None:
        with open(folder / log, "w") as fh:
            proc = subprocess.Popen(
                args,
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=None if env is None else dict(env),
                start_new_session=True,
            )
        procs.append(proc)
        if on_spawn is not None:
            on_spawn(proc)

    try:
        spawn([dask, "scheduler", *local, "--port", "0", "--scheduler-file", str(sched_file)], "scheduler.log")
        deadline = time.monotonic() + timeout
        address = _scheduler_address(sched_file, procs[0], deadline, timeout)
        worker_args = ["--nworkers", str(workers), "--nthreads", "1", "--local-directory", str(folder / "workers")]
        spawn([dask, "worker", address, *local, *worker_args], "workers.log")
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(workers, timeout=max(1.0, deadline - time.monotonic()))
        yield address
    finally:
        stop_groups(procs)


def _scheduler_address(sched_file: Path, scheduler: subprocess.Popen, deadline: float, timeout: float) -> str:
    """The address a starting ``dask scheduler`` writes to ``sched_file``, once it has (polled)."""
    while not (sched_file.exists() and sched_file.stat().st_size > 0):
        if time.monotonic() > deadline or scheduler.poll() is not None:
            raise TimeoutError(
                f"the Dask scheduler did not start within {timeout:.0f} s (see {sched_file.parent / 'scheduler.log'})"
            )
        time.sleep(0.2)
    return json.loads(sched_file.read_text())["address"]


def stop_groups(procs: list[subprocess.Popen]) -> None:
    """Stop the process groups of ``procs``, last started first: SIGTERM, then SIGKILL after 30 s."""
    for p in reversed(procs):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGTERM)
    for p in reversed(procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()
