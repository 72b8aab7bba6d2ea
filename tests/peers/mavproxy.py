"""MAVProxy (PyPI) driven as its users drive it: commands on its stdin (no terminal), its
console output read as it comes, each line stamped with the time it arrived
(time.monotonic()). Used by tests/peers and by the SITL rig (tests/sitl)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import List, Tuple

import pytest


def mavproxy_path() -> str:
    """mavproxy.py of this Python's environment; skips when MAVProxy is not installed."""
    try:
        import MAVProxy  # noqa: F401
    except ImportError as e:
        pytest.skip(f"MAVProxy cannot run here (pip install MAVProxy: {e})")
    return str(Path(sys.executable).with_name("mavproxy.py"))


def descendants(pid: int) -> List[int]:
    """Every process below `pid` (children first found, then theirs), from /proc."""
    children: dict = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


class MAVProxy:
    """mavproxy.py --master=MASTER [args] in `workdir` (its cwd and HOME: no user settings
    leak in), stdin a pipe, stdout+stderr read line by line into `lines` [(time, text)] and
    the file `name`.out."""

    def __init__(self, workdir: Path, master: str, args=(), name: str = "mavproxy"):
        workdir.mkdir(parents=True, exist_ok=True)
        self.workdir = workdir
        self.out_path = workdir / f"{name}.out"
        self._out = open(self.out_path, "w")
        self.lines: List[Tuple[float, str]] = []
        self._lock = threading.Lock()
        self.proc = subprocess.Popen(
            [mavproxy_path(), f"--master={master}", *args],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            cwd=workdir, env={"PYTHONUNBUFFERED": "1", "PATH": "/usr/bin:/bin",
                              "HOME": str(workdir)})
        self.started = time.monotonic()
        self._reader = threading.Thread(target=self._read, name=f"{name}-out", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for raw in iter(self.proc.stdout.readline, b""):
            line = raw.decode(errors="replace").rstrip("\n")
            with self._lock:
                self.lines.append((time.monotonic(), line))
                self._out.write(line + "\n")
                self._out.flush()

    def text(self) -> str:
        with self._lock:
            return "\n".join(l for _, l in self.lines)

    def send(self, line: str) -> float:
        """Writes one command; returns when it was written."""
        self.proc.stdin.write((line + "\n").encode())
        self.proc.stdin.flush()
        return time.monotonic()

    def find(self, pattern: str, since: float = 0.0) -> List[Tuple[float, re.Match]]:
        """(time, match) of every line since `since` (monotonic) that matches."""
        rx = re.compile(pattern)
        with self._lock:
            lines = list(self.lines)
        return [(t, m) for t, l in lines if t >= since and (m := rx.search(l))]

    def wait_for(self, pattern: str, count: int = 1, timeout: float = 60.0,
                 since: float = 0.0) -> List[Tuple[float, re.Match]]:
        """The first `count` lines matching `pattern` since `since`; fails after `timeout`."""
        deadline = time.monotonic() + timeout
        while True:
            expired = time.monotonic() >= deadline  # before the look: a line read meanwhile counts
            found = self.find(pattern, since)
            if len(found) >= count:
                return found[:count]
            assert self.proc.poll() is None, f"MAVProxy exited: {self.text()[-3000:]}"
            assert not expired, \
                f"MAVProxy: no {pattern!r} x{count} within {timeout} s: {self.text()[-3000:]}"
            time.sleep(0.05)

    def wait_any(self, patterns: dict, timeout: float, since: float) -> Tuple[str, float, re.Match]:
        """The first of several outcomes {name: pattern} to show since `since`, or ("timeout",
        now, None)."""
        deadline = time.monotonic() + timeout
        while self.proc.poll() is None:
            expired = time.monotonic() >= deadline  # before the look, as in wait_for
            hits = [(t, name, m) for name, p in patterns.items() for t, m in self.find(p, since)]
            if hits:
                t, name, m = min(hits, key=lambda h: h[0])
                return name, t, m
            if expired:
                break
            time.sleep(0.05)
        return "timeout", time.monotonic(), None

    def stop(self, grace: float = 5.0) -> None:
        """End of input (MAVProxy's own way to quit without a terminal), then SIGTERM, then
        SIGKILL, to it and whatever it started (its log writer's helpers)."""
        if self.proc.poll() is None:
            kids = descendants(self.proc.pid)
            try:
                self.proc.stdin.close()
            except OSError:
                pass
            for sig in (None, signal.SIGTERM, signal.SIGKILL):
                if sig is not None and self.proc.poll() is None:
                    self.proc.send_signal(sig)
                try:
                    self.proc.wait(grace)
                    break
                except subprocess.TimeoutExpired:
                    continue
            for pid in kids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        self._reader.join(5)
        with self._lock:
            self._out.close()
