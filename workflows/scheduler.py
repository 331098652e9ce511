"""``python -m workflows.scheduler``: Luigi's central scheduler (luigid), started safely.

luigid has no authentication, and it unpickles its state file at start-up, so two things decide
who can take over the machine it runs on: who can reach its port, and who can write its state
file. This launcher listens on 127.0.0.1 unless told otherwise, and keeps the state file and the
log in a folder only the current user can write (created with mode 0700; refused when it belongs
to someone else or others may write to it). See docs/distributed.md for several machines.
"""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import os
import stat
import sys
from pathlib import Path

from pipeline.core.settings_io import add_arguments, from_args, setting

LOOPBACK = "127.0.0.1"
STATE_FILE = "state.pickle"
LOG_DIR = "log"


class UnsafeStateDir(Exception):
    """The state folder could let another user feed luigid a pickle."""


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/sketch2patch/luigid`` (``~/.local/state/...`` when unset)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "sketch2patch" / "luigid"


def _check_private(path: Path, what: str) -> None:
    st = path.lstat()
    if stat.S_ISLNK(st.st_mode):
        raise UnsafeStateDir(f"{path}: {what} is a symbolic link; use a real folder")
    if st.st_uid != os.getuid():
        raise UnsafeStateDir(
            f"{path}: {what} belongs to uid {st.st_uid}, not to you (uid {os.getuid()}); "
            "luigid would load a pickle another user can write"
        )
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise UnsafeStateDir(
            f"{path}: {what} is writable by group or others (mode {stat.S_IMODE(st.st_mode):o}); "
            f"run `chmod go-w {path}` or choose another --state-dir"
        )


def private_state_dir(path: Path) -> Path:
    """``path`` made (mode 0700) or checked: owned by this user, not a link, nobody else may write
    to it or to the state file in it. Parents are created as the umask allows."""
    path = Path(path).expanduser().absolute()
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700)
        os.chmod(path, 0o700)  # mkdir's mode is masked by the umask
    if not path.is_dir():
        raise UnsafeStateDir(f"{path}: not a folder")
    _check_private(path, "the state folder")
    state = path / STATE_FILE
    if state.exists() or state.is_symlink():
        _check_private(state, "the state file")
    (path / LOG_DIR).mkdir(mode=0o700, exist_ok=True)  # luigid logs into it but does not create it
    return path


def is_loopback(address: str) -> bool:
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


def luigid_argv(state_dir: Path, address: str, port: int, background: bool = False) -> list[str]:
    """The arguments luigid gets: the address always explicit (luigid's own default is every
    interface), state file and log inside the private folder."""
    argv = [
        "--address",
        address,
        "--port",
        str(port),
        "--state-path",
        str(state_dir / STATE_FILE),
        "--logdir",
        str(state_dir / LOG_DIR),
    ]
    if background:
        argv += ["--background", "--pidfile", str(state_dir / "luigid.pid")]
    return argv


@dataclasses.dataclass(frozen=True)
class SchedulerSettings:
    address: str = setting(
        LOOPBACK,
        "interface to listen on (127.0.0.1: this machine only). Anything else must be on a network "
        "where every host is trusted: luigid has no authentication",
    )
    port: int = setting(8082, "port to listen on")
    state_dir: Path | None = setting(
        None,
        f"folder for {STATE_FILE} and {LOG_DIR}/ (default: $XDG_STATE_HOME/sketch2patch/luigid, ~/.local/state/... when unset); "
        "created with mode 0700, refused when another user owns it or may write to it",
    )
    background: bool = setting(False, "daemonize (pid file in the state folder)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workflows.scheduler", description=__doc__.split("\n\n")[0])
    add_arguments(p, SchedulerSettings)
    a = from_args(SchedulerSettings, p.parse_args(argv))
    try:
        state_dir = private_state_dir(a.state_dir or default_state_dir())
    except (UnsafeStateDir, OSError) as exc:
        print(f"python -m workflows.scheduler: error: {exc}", file=sys.stderr)
        return 2
    if not is_loopback(a.address):
        print(
            f"warning: luigid listens on {a.address}: anyone who reaches port {a.port} there can read and "
            "change the build's tasks (no authentication). Keep it on a trusted network, behind a "
            "firewall, or on 127.0.0.1 with SSH tunnels from the workers (docs/distributed.md).",
            file=sys.stderr,
        )
    from luigi.cmdline import luigid

    print(f"luigid on {a.address}:{a.port}, state and log in {state_dir}", file=sys.stderr, flush=True)
    luigid(luigid_argv(state_dir, a.address, a.port, a.background))
    return 0


if __name__ == "__main__":
    sys.exit(main())
