"""The task engine: in-process, a local Dask pool, and a real Dask cluster (scheduler + 2 workers)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from egovid.core.engine import EngineConfig, open_client, run_tasks, scheduler_address, steady_malloc
from egovid.core.errors import EgovidError


def square(x: int) -> int:
    return x * x


def fail_once(marker: str) -> str:
    """Raise on the first call (no marker yet), succeed afterwards."""
    p = Path(marker)
    if not p.exists():
        p.write_text("x")
        raise RuntimeError("first attempt fails")
    return "ok"


def die_once(marker: str) -> int:
    """Kill the worker process running this task on the first attempt; succeed on the retry."""
    p = Path(marker)
    if not p.exists():
        p.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


def always_fails(_: int) -> None:
    raise ValueError("never works")


def test_in_process_runs_every_item_and_retries():
    cfg = EngineConfig(workers=1, retries=1)
    out = {o.key: o.value for o in run_tasks(square, [1, 2, 3], config=cfg, keys=["a", "b", "c"])}
    assert out == {"a": 1, "b": 4, "c": 9}


def test_in_process_retry_then_failure(tmp_path):
    cfg = EngineConfig(workers=1, retries=1)
    [ok] = run_tasks(fail_once, [str(tmp_path / "m")], config=cfg)
    assert ok.ok and ok.value == "ok"
    [bad] = run_tasks(always_fails, [0], config=EngineConfig(workers=1, retries=2))
    assert not bad.ok and isinstance(bad.error, ValueError)


def test_scheduler_address_from_option_or_dask_variable(monkeypatch):
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    assert scheduler_address(None) is None
    assert scheduler_address("tcp://10.0.0.1:8786") == "tcp://10.0.0.1:8786"
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:9999")
    assert scheduler_address(None) == "tcp://127.0.0.1:9999"
    with pytest.raises(EgovidError):
        scheduler_address("localhost")


def test_bad_worker_count_is_a_user_error():
    with pytest.raises(EgovidError):
        EngineConfig(workers=0)


def test_unreachable_scheduler_is_one_clear_error():
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # run_tasks opens its client through open_client; a short connect timeout keeps the test quick
    with (
        pytest.raises(EgovidError, match="cannot reach the Dask scheduler"),
        open_client(EngineConfig(scheduler=f"tcp://127.0.0.1:{port}"), connect_timeout=3),
    ):
        pass


def child_malloc_setting(_item) -> str:
    """The MALLOC_TRIM_THRESHOLD_ a process started by this task would inherit."""
    import subprocess
    import sys

    code = "import os; print(os.environ.get('MALLOC_TRIM_THRESHOLD_'))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def worker_start_malloc_setting(_item) -> str:
    """The MALLOC_TRIM_THRESHOLD_ this process was started with (its exec-time environment: an
    earlier task's steady_malloc in the same worker does not change it)."""
    with open("/proc/self/environ", "rb") as fh:
        env = dict(kv.split(b"=", 1) for kv in fh.read().split(b"\0") if b"=" in kv)
    return str(env.get(b"MALLOC_TRIM_THRESHOLD_", b"None").decode())


def test_tasks_undo_the_dask_nanny_malloc_setting(dask_scheduler):
    from distributed import Client

    # the control: the nanny starts its workers with the setting (1.8x the CPU time of a video
    # task). Read from the worker's start environment: the session's cluster is shared, and a
    # worker that already ran an engine task has it removed for good (a bare task's child would
    # then see None too, whatever the order of the tests).
    if os.path.exists("/proc/self/environ"):
        with Client(dask_scheduler, timeout=60) as client:
            assert client.submit(worker_start_malloc_setting, 0, pure=False).result(timeout=120) == "65536"
    [outcome] = run_tasks(child_malloc_setting, [0], config=EngineConfig(scheduler=dask_scheduler))
    assert outcome.value == "None"
    if os.uname().sysname == "Linux":
        assert steady_malloc()


def test_cluster_runs_tasks_and_retries_after_a_killed_worker(dask_scheduler, tmp_path):
    cfg = EngineConfig(scheduler=dask_scheduler, retries=1)
    results = {o.key: o.value for o in run_tasks(square, range(6), config=cfg, name="sq")}
    assert results == {str(i): i * i for i in range(6)}
    # identical arguments still run as separate tasks (pure=False): both come back
    assert len(list(run_tasks(square, [5, 5], config=cfg))) == 2
    marker = tmp_path / "died"
    [outcome] = run_tasks(die_once, [str(marker)], config=cfg, name="die")
    assert marker.exists(), "the first attempt never ran"
    assert outcome.ok, outcome.error
    assert outcome.value != int(marker.read_text()), "the retry ran in the process that was killed"


def test_local_pool_of_two_processes(tmp_path):
    cfg = EngineConfig(workers=2, retries=1)
    outcomes = list(run_tasks(fail_once, [str(tmp_path / "a"), str(tmp_path / "b")], config=cfg))
    assert all(o.ok and o.value == "ok" for o in outcomes)


def stamp(path: str) -> tuple[float, float]:
    """Sleep a little and return (start, end) wall-clock times."""
    import time

    t0 = time.time()
    time.sleep(0.3)
    Path(path).write_text("done")
    return t0, time.time()


def test_a_task_starts_after_the_tasks_it_waits_for(tmp_path):
    items = [str(tmp_path / k) for k in "abc"]
    after = {"c": ["a", "b"], "b": ["a"]}
    for cfg in (EngineConfig(workers=1), EngineConfig(workers=2)):
        out = {o.key: o.value for o in run_tasks(stamp, items, config=cfg, keys=["c", "b", "a"], after=after)}
        assert out["b"][0] >= out["a"][1] and out["c"][0] >= out["b"][1], out


def test_another_client_opened_and_closed_meanwhile_does_not_stall_the_run(dask_scheduler):
    """A second Client in this process becomes Dask's default client; closing it while a run is
    waiting must not stall the run (its completion tracking runs on the run's own client's loop)."""
    import threading

    from distributed import Client

    after = {"b": ["a"], "c": ["b"]}
    with Client(dask_scheduler, timeout=60, set_as_default=False) as own:
        other = Client(dask_scheduler, timeout=60)  # the default client from now on
        try:
            runs = run_tasks(
                square, [1, 2, 3], config=EngineConfig(scheduler=dask_scheduler), keys="abc", client=own, after=after
            )
            first = next(runs)  # the run is under way (task "a" finished, "b" submitted)
        finally:
            other.close()
        rest: list = []
        t = threading.Thread(target=lambda: rest.extend(runs), daemon=True)
        t.start()
        t.join(60)
        assert not t.is_alive(), "the run stalled after another client closed"
    assert {o.key: o.value for o in [first, *rest]} == {"a": 1, "b": 4, "c": 9}
