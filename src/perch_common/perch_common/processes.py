"""Child processes: stopping them the way Ctrl-C would, making them die with the process that
started them, and clearing the shared memory that killed Fast DDS processes leave behind."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

PARENT_ENV = "PERCH_PARENT_PID"   # set by a launcher for its node processes: die when that process is gone
PR_SET_PDEATHSIG = 1              # linux/prctl.h
ORPHAN_CHECK_PERIOD = 0.5         # s between checks that the launcher is still there
ORPHAN_KILL_AFTER = 5.0           # s a node may take to stop cleanly once its launcher is gone
SHM_DIR = Path("/dev/shm")
SHM_MIN_AGE = 10.0                # s: a younger lock file may belong to a process still setting it up


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> int | None:
    """SIGINT (nodes shut down cleanly), then SIGKILL after `timeout` seconds."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def child_environment(env: dict) -> dict:
    """`env` for a node process this process starts: the node will die with this process."""
    return {**env, PARENT_ENV: str(os.getpid())}


def signal_at_parent_death(signum: int) -> None:
    """Have Linux send `signum` to this process when the thread that started it ends (prctl
    PR_SET_PDEATHSIG; nothing elsewhere). Check the parent is still there after calling it."""
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum, 0, 0, 0)


def die_with_parent(env: dict | None = None) -> bool:
    """In a node process started by a Perch launcher (PERCH_PARENT_PID set): end when the launcher
    ends, however it ends (SIGKILL included). Returns whether the guard is on.

    Linux delivers SIGTERM at the launcher's death (prctl PR_SET_PDEATHSIG; rclpy shuts the node down
    on it); a watch thread notices the re-parenting too (and covers the launcher dying before the
    prctl) and kills the process if it has not stopped ORPHAN_KILL_AFTER seconds later."""
    # taken out of the environment: a process this node starts has another parent
    value = (os.environ if env is None else env).pop(PARENT_ENV, "")
    if not value.isdigit():
        return False
    parent = int(value)
    signal_at_parent_death(signal.SIGTERM)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_CHECK_PERIOD)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(ORPHAN_KILL_AFTER)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="perch-orphan-guard", daemon=True).start()
    return True


_SEGMENT = re.compile(r"^fastrtps_[0-9a-z]{16}$")
_PORT = re.compile(r"^fastrtps_port\d{1,5}$")


def _locked(path: Path) -> bool:
    """Whether a live process holds the Fast DDS lock file (the kernel drops a dead process's locks)."""
    import fcntl

    try:
        with open(path, "ab") as stream:
            fcntl.flock(stream, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(stream, fcntl.LOCK_UN)
            return False
    except OSError:
        return True


def dead_shm_files(shm_dir: Path = SHM_DIR, min_age: float | None = None) -> list[Path]:
    """Fast DDS shared-memory files of processes that died without closing them.

    Fast DDS names a participant's segment `fastrtps_<16 hex>` and a listening port `fastrtps_port<N>`,
    each with lock files (`_el`, `_sl`) that every live user holds locked (the port also has
    `sem.fastrtps_port<N>_mutex`); eProsima's `fastdds shm clean` decides the same way. Conservative:
    only files of this user, whose lock files exist, are all unlocked and are older than `min_age`."""
    min_age = SHM_MIN_AGE if min_age is None else min_age
    try:
        names = set(os.listdir(shm_dir))
    except OSError:
        return []
    now, uid, dead = time.time(), os.getuid(), []
    for name in sorted(names):
        if not (_SEGMENT.match(name) or _PORT.match(name)):
            continue
        locks = [shm_dir / f"{name}{suffix}" for suffix in ("_el", "_sl") if f"{name}{suffix}" in names]
        if not locks:
            continue
        try:
            stats = [lock.stat() for lock in locks]
        except OSError:
            continue
        if any(s.st_uid != uid or now - s.st_mtime < min_age for s in stats) or any(_locked(p) for p in locks):
            continue
        files = [shm_dir / name, *locks]
        if name.startswith("fastrtps_port") and f"sem.{name}_mutex" in names:
            files.append(shm_dir / f"sem.{name}_mutex")
        dead.extend(files)
    return dead


def clean_dead_shm(shm_dir: Path = SHM_DIR, min_age: float | None = None) -> int:
    """Remove dead_shm_files; returns how many files went."""
    removed = 0
    for path in dead_shm_files(shm_dir, min_age):
        with contextlib.suppress(OSError):
            path.unlink()
            removed += 1
    return removed
