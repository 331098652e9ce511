"""``python -m workflows.scheduler``: luigid on loopback, its pickled state in a private folder."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from workflows.scheduler import STATE_FILE, UnsafeStateDir, is_loopback, luigid_argv, main, private_state_dir

ROOT = Path(__file__).resolve().parents[1]


def test_state_dir_is_created_private(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        d = private_state_dir(tmp_path / "a" / "luigid")
    finally:
        os.umask(old)
    assert stat.S_IMODE(d.stat().st_mode) == 0o700
    assert (d / "log").is_dir()


def test_group_writable_state_dir_is_refused(tmp_path: Path) -> None:
    d = tmp_path / "shared"
    d.mkdir()
    os.chmod(d, 0o777)
    with pytest.raises(UnsafeStateDir, match="writable by group or others"):
        private_state_dir(d)


def test_writable_state_file_is_refused(tmp_path: Path) -> None:
    d = private_state_dir(tmp_path / "luigid")
    (d / STATE_FILE).write_bytes(b"")
    os.chmod(d / STATE_FILE, 0o666)
    with pytest.raises(UnsafeStateDir, match="the state file is writable"):
        private_state_dir(d)


def test_symlinked_state_dir_is_refused(tmp_path: Path) -> None:
    (tmp_path / "real").mkdir(mode=0o700)
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with pytest.raises(UnsafeStateDir, match="symbolic link"):
        private_state_dir(tmp_path / "link")


@pytest.mark.skipif(os.getuid() != 0, reason="handing a folder to another user needs root")
def test_state_dir_of_another_user_is_refused(tmp_path: Path) -> None:
    d = tmp_path / "theirs"
    d.mkdir(mode=0o700)
    os.chown(d, 65534, 65534)
    with pytest.raises(UnsafeStateDir, match="belongs to uid 65534"):
        private_state_dir(d)


def test_refusal_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    d = tmp_path / "open"
    d.mkdir()
    os.chmod(d, 0o757)
    assert main(["--state-dir", str(d)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(d) in err and "writable by group or others" in err


def test_address_is_always_explicit_and_loopback_by_default(tmp_path: Path) -> None:
    argv = luigid_argv(tmp_path, "127.0.0.1", 8082)
    assert argv[argv.index("--address") + 1] == "127.0.0.1"
    assert argv[argv.index("--state-path") + 1] == str(tmp_path / STATE_FILE)
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("10.0.0.5")


def _listening_addresses(pid: int) -> set[str]:
    """Local addresses of the process's listening TCP sockets (from /proc, IPv4 only)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = set()
    for line in Path(f"/proc/{pid}/net/tcp").read_text().splitlines()[1:]:
        cols = line.split()
        if cols[3] == "0A" and cols[9] in inodes:  # 0A: LISTEN
            hex_ip = cols[1].split(":")[0]
            out.add(socket.inet_ntoa(bytes.fromhex(hex_ip)[::-1]))
    return out


def test_scheduler_listens_on_loopback_only_and_keeps_state_private(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    state = tmp_path / "luigid"
    proc = subprocess.Popen(
        [sys.executable, "-m", "workflows.scheduler", "--port", str(port), "--state-dir", str(state)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not _listening_addresses(proc.pid):
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            assert time.monotonic() < deadline, "luigid did not start"
            time.sleep(0.2)
        assert _listening_addresses(proc.pid) == {"127.0.0.1"}
    finally:
        proc.terminate()  # luigid saves its state on SIGTERM
        proc.wait(timeout=30)
    assert (state / STATE_FILE).is_file()
    assert stat.S_IMODE(state.stat().st_mode) == 0o700
