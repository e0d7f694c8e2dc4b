"""One function call run in a forked child process while the caller works on, with a deadline.

A pure, CPU-bound call that holds the GIL (an LP solve) gets the second core this way. A child
forked from a process with other threads can deadlock on a lock one of them held at the fork, or
be killed (out of memory); then the caller would wait for ever. So the result is fetched with a
deadline, and a child that has not answered by then (or died) is killed and the call is made
again in the caller: the same function on the same inputs, so the same result, only later.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from typing import Any


def can_fork() -> bool:
    """Whether this process may fork a child here: the platform can fork and this process is not
    itself a daemonic child (Dask workers, multiprocessing pool workers may not have children)."""
    return "fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon


def _child(send, fn: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    try:
        out = (True, fn(*args, **kwargs))
    except BaseException as exc:  # handed to the caller, raised there
        out = (False, exc)
    try:
        send.send(out)
    finally:
        send.close()


class SideCall:
    """``fn(*args, **kwargs)`` started in a forked child; :meth:`result` returns its value."""

    def __init__(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        ctx = multiprocessing.get_context("fork")
        self._call = (fn, args, kwargs)
        self._recv, send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_child, args=(send, fn, args, kwargs), daemon=True)
        self._proc.start()
        send.close()  # the child holds the only writer: its death reads as EOF here

    def result(self, deadline_s: float) -> Any:
        """The call's value: the child's if it answers within ``deadline_s`` seconds (an exception
        it raised is raised here), else the call made here after the child is killed."""
        answer = None
        try:
            if self._recv.poll(deadline_s):
                answer = self._recv.recv()
        except (EOFError, OSError):
            answer = None
        finally:
            self.close()
        if answer is None:
            fn, args, kwargs = self._call
            return fn(*args, **kwargs)
        ok, value = answer
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop the child if it is still running and release the pipe (idempotent)."""
        if self._proc.is_alive():
            self._proc.kill()
        self._proc.join(timeout=10)
        self._recv.close()
