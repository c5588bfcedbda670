"""A forked child gets a working launch pool (the kill-9 harness forks the test process
after other tests have started the pool: the inherited pool has no threads in the child,
and a split launch there waited forever)."""

from __future__ import annotations

import os
import sys
import time

import pytest

from divas_kernels import _launch


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_pool_works_in_a_forked_child():
    assert _launch._pool(2).submit(lambda: 41).result(timeout=30) == 41  # parent's pool up
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # child: a split launch's pool must run work
        code = 1
        try:
            fut = _launch._pool(2).submit(lambda: 42)
            code = 0 if fut.result(timeout=20) == 42 else 2
        except BaseException:
            code = 3
        finally:
            os._exit(code)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            assert os.waitstatus_to_exitcode(status) == 0
            return
        time.sleep(0.01)
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    pytest.fail("the forked child's pool never ran its work")
