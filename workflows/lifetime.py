"""Task processes end with the process that started them.

With ``--workers N`` (N > 1) Luigi runs each task in a forked process. Killing the `luigi` (or
`make dataset`) process, even with SIGKILL, would leave those running, each with its Blender
worker, writing into the work folder with no scheduler. A task process therefore asks Linux to
SIGKILL it when its parent dies (PR_SET_PDEATHSIG; a watchdog thread where prctl is missing);
its Blender worker dies with it in turn (render.worker.die_with_parent). Every output is written
atomically, so a kill at any moment leaves nothing half-done (tests/test_faults_kill.py).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import threading
import time

_PR_SET_PDEATHSIG = 1
_armed_in: list[int] = []  # pids of processes already armed (once per process is enough)


def die_with_parent() -> bool:
    """In a process forked by multiprocessing (Luigi's task processes): be killed when the
    parent dies. Returns whether it armed now; the main process (workers=1) is left alone."""
    parent = multiprocessing.parent_process()
    if parent is None or os.getpid() in _armed_in:
        return False
    _armed_in.append(os.getpid())
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):
        threading.Thread(target=_watch, args=(parent.pid,), daemon=True).start()
    if os.getppid() != parent.pid:  # the parent died before the request took effect
        os._exit(1)
    return True


def _watch(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(1.0)
    os._exit(1)
