"""Run a function as another user in a forked child (permission tests: root reads mode-000 files)."""

from __future__ import annotations

import os
from typing import Callable


def call_as(uid_gid: tuple[int, int] | None, fn: Callable[[], str]) -> str:
    """``fn()`` in a forked child that first drops to ``uid_gid`` (None: stays this user).
    Returns what ``fn`` returned, or ``"<ExceptionType>: <message>"`` of what it raised."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: never returns into pytest
        os.close(r)
        try:
            if uid_gid is not None:
                os.setgid(uid_gid[1])
                os.setuid(uid_gid[0])
            msg = fn()
        except BaseException as e:  # noqa: BLE001 - report anything to the parent
            msg = f"{type(e).__name__}: {e}"
        os.write(w, msg.encode())
        os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        out = f.read().decode()
    os.waitpid(pid, 0)
    return out
