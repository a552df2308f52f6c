"""Who holds a work claim, and whether that holder is provably dead.

A claim records its holder's host, process id, process start time and a readable worker name. On
the holder's own host, another process can tell for certain that the holder is gone: its pid no
longer exists (or is a zombie), or the pid was reused by a process that started at another time.
Such claims are taken over at once instead of blocking their items for the whole lease. On
another host nothing is provable, so a claim there is only taken over once its lease expires.

Assumes one pid namespace per host name (containers that share a host name must not share a
database with different pid namespaces; Docker gives each container its own host name).
"""

from __future__ import annotations

import os
import socket
import sys
from dataclasses import dataclass
from pathlib import Path

_name: str | None = None


@dataclass(frozen=True)
class Holder:
    """One worker process: where it runs, its pid and start time, and a name people recognise."""

    host: str
    pid: int
    started: str  # the process start time in clock ticks since boot ("" where /proc is absent)
    name: str

    @property
    def worker(self) -> str:
        """The claim's `worker` value: unique among live processes across machines."""
        return f"{self.host}:{self.pid}"


def set_worker_name(name: str) -> None:
    """Name this process's claims (e.g. a flow run's name) instead of its command line."""
    global _name
    _name = name


def worker_name() -> str:
    """The name set with `set_worker_name`, else the command ("photoshape run", "pytest")."""
    if _name is not None:
        return _name
    command = sys.argv[0] if sys.argv else ""
    argv = [Path(command).name if command and not command.startswith("-") else "python"]
    if len(sys.argv) > 1 and not sys.argv[1].startswith("-"):
        argv.append(sys.argv[1])
    return " ".join(argv)[:128]


def process_start(pid: int) -> str | None:
    """`pid`'s start time (clock ticks since boot, as /proc reports it); None: no such live process.

    A zombie (killed, not yet reaped) counts as gone. Without /proc (not Linux) the start time is
    unknown (""), and only a missing pid is detected.
    """
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        if Path("/proc/self/stat").exists():
            return None
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return ""
    except OSError:
        return ""
    fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (comm) ": state is field 3, starttime 22
    return None if fields[0] in ("Z", "X") else fields[19]


def this_process() -> Holder:
    """The holder this process records on its claims (recomputed after a fork: the pid changes)."""
    pid = os.getpid()
    return Holder(socket.gethostname(), pid, process_start(pid) or "", worker_name())


def is_dead(host: str | None, pid: int | None, started: str | None) -> bool:
    """True only when the holder provably no longer runs: same host, and its pid is gone or reused."""
    if host != socket.gethostname() or pid is None:
        return False
    now = process_start(pid)
    if now is None:
        return True
    return bool(started) and bool(now) and now != started
