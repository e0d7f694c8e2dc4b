"""SideCall: a call in a forked child with a deadline; a child that hangs or dies is replaced by
the same call made in the caller, so a plan never waits for ever on its side process."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from egovid.core.side_call import SideCall, can_fork

pytestmark = pytest.mark.skipif(not can_fork(), reason="this platform cannot fork")


def _square(x: np.ndarray) -> np.ndarray:
    return x**2


def _pid_then(hang: bool, caller: int) -> int:
    """In a child: hang (sleep) or die; in the caller: its pid."""
    if os.getpid() != caller:
        if hang:
            time.sleep(60)
        os._exit(3)
    return os.getpid()


def _fail() -> None:
    raise ValueError("bad axis")


def test_the_child_answers_with_the_calls_value():
    x = np.arange(200_000, dtype=np.float64)  # 1.6 MB each way: more than a pipe buffer
    np.testing.assert_array_equal(SideCall(_square, x).result(60.0), x**2)


@pytest.mark.parametrize("hang", [True, False], ids=["hangs", "dies"])
def test_a_child_that_hangs_or_dies_is_replaced_by_the_call_made_here(hang):
    t0 = time.perf_counter()
    call = SideCall(_pid_then, hang, os.getpid())
    assert call.result(2.0) == os.getpid()  # made in the caller
    assert time.perf_counter() - t0 < 30  # the deadline, not the child's 60 s sleep
    assert not call._proc.is_alive()


def test_the_childs_exception_is_raised_in_the_caller():
    with pytest.raises(ValueError, match="bad axis"):
        SideCall(_fail).result(60.0)
