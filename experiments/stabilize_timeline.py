"""Wall-clock timeline of one ``egovid fpv stabilize IN -o OUT --no-measure`` run: which stage
runs when and how many cores the process (its threads and children) keeps busy.

Runs the command in this process (``egovid.cli.main``), wrapping the stage functions to stamp
their start and end (seconds since the process started, from ``/proc/self/stat``), while a
sampler thread reads every thread's and child's user + system CPU time from ``/proc`` every
``--dt`` seconds. Prints the stages and, per bin, the CPU seconds used per wall second (cores
busy, at most the machine's 2) split into the main thread, the other Python threads and the
native threads (FFmpeg, x264, OpenCV pools) and child processes. The sampler's own cost (about
1 % of a core at 0.1 s) is in the figures.

    python experiments/stabilize_timeline.py CLIP OUT [--dt 0.25]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import threading
from pathlib import Path

TICK = os.sysconf("SC_CLK_TCK")


def _stat(path: str) -> list[str]:
    """The fields of a ``/proc/.../stat`` file after the command name."""
    return Path(path).read_text().rsplit(")", 1)[1].split()


START = float(_stat("/proc/self/stat")[19]) / TICK


def _uptime() -> float:
    return float(Path("/proc/uptime").read_text().split()[0])


def now() -> float:
    """Seconds since this process started."""
    return _uptime() - START


def _cpu(stat_path: str) -> float:
    f = _stat(stat_path)
    return (int(f[11]) + int(f[12])) / TICK


def _children(pid: int) -> list[int]:
    out = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            kids = Path(f"/proc/{pid}/task/{tid}/children").read_text().split()
        except OSError:
            continue
        for c in kids:
            out.append(int(c))
            out.extend(_children(int(c)))
    return out


def sample() -> dict[str, float]:
    """CPU seconds so far of every thread of this process (by ``tid``) and of every child (whole)."""
    pid = os.getpid()
    cpu = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(OSError):
            cpu[f"t{tid}"] = _cpu(f"/proc/{pid}/task/{tid}/stat")
    for c in _children(pid):
        with contextlib.suppress(OSError):  # the child's own CPU and its waited-for children's
            cpu[f"c{c}"] = _cpu(f"/proc/{c}/stat") + sum(int(x) / TICK for x in _stat(f"/proc/{c}/stat")[13:15])
    return cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip")
    ap.add_argument("out")
    ap.add_argument("--dt", type=float, default=0.25)
    ap.add_argument("--threads", action="store_true", help="also the CPU of each Python thread (by name) per bin")
    args = ap.parse_args()
    t_imports = now()
    import egovid.cli as cli
    import egovid.fpv.stabilize.pipeline as pl
    import egovid.fpv.stabilize.run as run

    stages: list[tuple[str, float, float]] = []

    def stamped(mod, name, label):
        fn = getattr(mod, name)

        def wrapper(*a, **kw):
            t = now()
            try:
                return fn(*a, **kw)
            finally:
                stages.append((label, t, now()))

        setattr(mod, name, wrapper)

    stamped(run, "camera_motion", "motion")
    stamped(pl, "plan_motion", "plan")
    stamped(pl, "visible_path", "path fit")
    stamped(pl, "fit_path", "path fit")
    stamped(pl, "render_stabilized", "render")
    stamped(pl, "_render_views", "render")
    names: dict[str, str] = {}
    py_names: dict[str, str] = {}  # Python thread names, for --threads
    samples: list[tuple[float, dict[str, float]]] = []
    stop = threading.Event()

    def sampler():
        while not stop.is_set():
            for th in threading.enumerate():
                if th.native_id is not None:
                    names.setdefault(f"t{th.native_id}", "main" if th is threading.main_thread() else "py")
                    py_names.setdefault(f"t{th.native_id}", th.name.split("_")[0])
            samples.append((now(), sample()))
            stop.wait(args.dt)

    me = threading.Thread(target=sampler, daemon=True)
    me.start()
    t_cli = now()
    with contextlib.suppress(SystemExit):
        cli.main(["fpv", "stabilize", args.clip, "-o", args.out, "--no-measure"])
    stop.set()
    me.join(timeout=5)
    samples.append((now(), sample()))
    print(f"process start 0.00, imports {t_imports:.2f}-{t_cli:.2f} s")
    for label, a, b in stages:
        print(f"{label:9s} {a:6.2f} - {b:6.2f} s ({b - a:5.2f})")
    print("  t (s)  cores  main   py-threads  native+children   stage")
    total = {"main": 0.0, "py": 0.0, "native": 0.0}
    for (t0, s0), (t1, s1) in itertools.pairwise(samples):
        dt = t1 - t0
        if dt <= 0:
            continue
        part = {"main": 0.0, "py": 0.0, "native": 0.0}
        for k, v in s1.items():
            d = v - s0.get(k, 0.0 if k.startswith("t") else v)
            part[names.get(k, "native")] += max(d, 0.0)
        for k in part:
            total[k] += part[k]
        at = [label for label, a, b in stages if a <= t1 and b >= t0]
        if args.threads:
            by: dict[str, float] = {}
            for k, v in s1.items():
                if k in py_names and names.get(k) == "py":
                    by[py_names[k]] = by.get(py_names[k], 0.0) + max(v - s0.get(k, 0.0), 0.0)
            at.append(" ".join(f"{n}:{c / dt:.2f}" for n, c in by.items() if c > 0))
        print(
            f"{t1:7.2f}  {sum(part.values()) / dt:4.2f}  {part['main'] / dt:4.2f}  {part['py'] / dt:4.2f}"
            f"        {part['native'] / dt:4.2f}            {','.join(dict.fromkeys(at))}"
        )
    first = samples[0][1]
    print(
        f"CPU-s from {samples[0][0]:.2f} s: main {total['main']:.2f}, py threads {total['py']:.2f}, "
        f"native+children {total['native']:.2f}; before it {sum(v for k, v in first.items()):.2f}"
    )
    ru = os.times()
    print(f"os.times: user {ru.user:.2f} sys {ru.system:.2f} children {ru.children_user + ru.children_system:.2f}")


if __name__ == "__main__":
    main()
