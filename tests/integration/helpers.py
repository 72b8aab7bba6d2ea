"""Helpers for the integration tests: run the real mavbond binary with a temporary config,
read its counters, talk to it over UDP/TCP/pty, build frames with pymavlink."""
from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import threading
import tty
from pathlib import Path
from typing import Callable, Dict, Iterable, List, Optional

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "tools"))

import tlog  # noqa: E402  (tests/tools/tlog.py)
from pymavlink.dialects.v10 import all as mav1  # noqa: E402
from pymavlink.dialects.v20 import all as mav2  # noqa: E402

HOST = "127.0.0.1"
BIG_RCVBUF = 8 * 1024 * 1024

STATS_RE = re.compile(r"stats endpoint=(\S+) kind=(\S+) (.*)$")


# --- config -------------------------------------------------------------------------------

def _yaml_scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_yaml_scalar(x) for x in v) + "]"
    return str(v)


def make_config(endpoints: List[dict], **top) -> str:
    """YAML text: top-level scalars, then one flow mapping per endpoint."""
    lines = [f"{k}: {_yaml_scalar(v)}" for k, v in top.items()]
    lines.append("endpoints:")
    for ep in endpoints:
        body = ", ".join(f"{k}: {_yaml_scalar(v)}" for k, v in ep.items())
        lines.append(f"  - {{{body}}}")
    return "\n".join(lines) + "\n"


def udp_server(name: str, port: int, **kw) -> dict:
    return {"name": name, "type": "udp", "mode": "server", "address": f"{HOST}:{port}", **kw}


def udp_client(name: str, port: int, **kw) -> dict:
    return {"name": name, "type": "udp", "mode": "client", "address": f"{HOST}:{port}", **kw}


def tcp_server(name: str, port: int, **kw) -> dict:
    return {"name": name, "type": "tcp", "mode": "server", "address": f"{HOST}:{port}", **kw}


def tcp_client(name: str, port: int, **kw) -> dict:
    return {"name": name, "type": "tcp", "mode": "client", "address": f"{HOST}:{port}", **kw}


def uart(name: str, device: str, baud: int = 921600, **kw) -> dict:
    return {"name": name, "type": "uart", "device": device, "baud": baud, **kw}


# --- ports --------------------------------------------------------------------------------

# Ports for the tests' own servers come from below the kernel's ephemeral range
# (net.ipv4.ip_local_port_range, 32768-60999 by default): a port the kernel hands out for an
# implicit bind (a client socket, an emulator's source port) can never be one of them, so
# a port chosen here cannot be taken between the choice and the bind. Each process starts at
# its own place in the range and walks on. MAVBOND_TEST_PORTS=LOW-HIGH narrows the range, so
# that two test runs at once (scripts/test runs the sanitizer build's beside the plain one)
# never choose the same port.
_PORT_LOW, _PORT_HIGH = (int(p) for p in os.environ.get("MAVBOND_TEST_PORTS", "10000-32767")
                         .split("-"))
_next_port = _PORT_LOW + (os.getpid() * 7919) % (_PORT_HIGH - _PORT_LOW)


def free_port(kind=socket.SOCK_DGRAM) -> int:
    """A port below the ephemeral range, free on 127.0.0.1 for both UDP and TCP now, and not
    handed out before by this process."""
    global _next_port
    for _ in range(_PORT_HIGH - _PORT_LOW):
        port = _next_port
        _next_port = _PORT_LOW if _next_port >= _PORT_HIGH else _next_port + 1
        try:
            for k in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
                with socket.socket(socket.AF_INET, k) as s:
                    s.bind((HOST, port))
            return port
        except OSError:
            continue
    raise RuntimeError("no free port")


def udp_socket(port: int = 0, rcvbuf: int = BIG_RCVBUF) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.bind((HOST, port))
    return s


def recv_datagrams(sock: socket.socket, count: Optional[int] = None, timeout: float = 5.0,
                   quiet: float = 0.3) -> List[bytes]:
    """Receives datagrams until `count` arrived (or, with count None, until the socket was
    quiet for `quiet` seconds), or `timeout` passed. Tests that must see nothing extra call
    it again with count None."""
    out: List[bytes] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if count is not None and len(out) >= count:
            break
        wait = min(quiet if count is None else 0.2, max(0.01, deadline - time.monotonic()))
        sock.settimeout(wait)
        try:
            out.append(sock.recv(65536))
        except socket.timeout:
            if count is None:
                break
    sock.settimeout(None)
    return out


def drain(sock: socket.socket) -> int:
    """Throws away whatever is queued on a socket; returns how many datagrams."""
    n = 0
    sock.setblocking(False)
    try:
        while True:
            sock.recv(65536)
            n += 1
    except BlockingIOError:
        pass
    sock.setblocking(True)
    return n


def send_paced(sock: socket.socket, addr, datagrams: Iterable[bytes], burst: int = 200,
               pause: float = 0.002) -> int:
    n = 0
    for d in datagrams:
        sock.sendto(d, addr)
        n += 1
        if n % burst == 0:
            time.sleep(pause)
    return n


def send_lockstep(sock: socket.socket, addr, frames: List[bytes], sink: socket.socket,
                  burst: int = 50, timeout: float = 3.0) -> List[bytes]:
    """Sends frames one per datagram in bursts, waiting after each burst until `sink` (a
    socket that receives every one of them through the daemon) got them, so no socket
    buffer overflows however slow the machine is. Returns the frames `sink` received."""
    got: List[bytes] = []
    for i in range(0, len(frames), burst):
        for f in frames[i:i + burst]:
            sock.sendto(f, addr)
        want = min(i + burst, len(frames))
        for dg in recv_datagrams(sink, want - len(got), timeout=timeout):
            got += split_stream(dg)
    return got


# --- frames -------------------------------------------------------------------------------

class FrameMaker:
    """Packs frames with pymavlink for one (sysid, compid). pymavlink's pack() does not count:
    every frame has sequence number 0 (tests that send the same frame twice rely on it) unless
    `counting`, which numbers them as a MAVLink stack's send() does, one up per frame."""

    def __init__(self, sysid: int, compid: int, v1: bool = False, counting: bool = False):
        mod = mav1 if v1 else mav2
        self.mav = mod.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mod = mod
        self.counting = counting

    def pack(self, msg) -> bytes:
        frame = bytes(msg.pack(self.mav))
        if self.counting:
            self.mav.seq = (self.mav.seq + 1) % 256
        return frame

    def heartbeat(self, type_=2) -> bytes:
        return self.pack(self.mod.MAVLink_heartbeat_message(type_, 3, 0, 0, 4, 3))

    def attitude(self, t_ms: int) -> bytes:
        return self.pack(self.mod.MAVLink_attitude_message(t_ms, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03))

    def sys_status(self) -> bytes:
        return self.pack(self.mod.MAVLink_sys_status_message(1, 1, 1, 500, 12000, -1, 80, 0, 0, 0, 0, 0, 0))

    def command_long(self, target_system: int, target_component: int, command: int = 400) -> bytes:
        return self.pack(self.mod.MAVLink_command_long_message(
            target_system, target_component, command, 0, 1, 0, 0, 0, 0, 0, 0))

    def param_request_read(self, target_system: int, target_component: int) -> bytes:
        return self.pack(self.mod.MAVLink_param_request_read_message(
            target_system, target_component, b"SYSID_THISMAV", -1))

    def telemetry(self, n: int) -> List[bytes]:
        """n frames of mixed telemetry: ATTITUDE, SYS_STATUS, HEARTBEAT."""
        out = []
        for i in range(n):
            if i % 10 == 0:
                out.append(self.heartbeat())
            elif i % 3 == 0:
                out.append(self.sys_status())
            else:
                out.append(self.attitude(i * 10))
        return out


def raw_v2_frame(msgid: int, payload: bytes, sysid: int = 1, compid: int = 1, seq: int = 0,
                 crc: Optional[int] = None) -> bytes:
    """A v2 frame with any msgid (the CRC is computed with crc_extra 0 when the id is
    unknown, unless given)."""
    hdr = bytes([0xFD, len(payload), 0, 0, seq, sysid, compid,
                 msgid & 0xFF, (msgid >> 8) & 0xFF, (msgid >> 16) & 0xFF])
    body = hdr + payload
    if crc is None:
        extra = tlog.crc_extras().get(msgid, 0)
        frame0 = body + b"\0\0"
        crc = tlog.compute_crc(frame0, extra)
    return body + bytes([crc & 0xFF, crc >> 8])


def corrupt_crc(frame: bytes) -> bytes:
    b = bytearray(frame)
    b[-1] ^= 0x5A
    return bytes(b)


# --- processes ------------------------------------------------------------------------------

def terminate(proc: subprocess.Popen, grace: float = 10.0) -> Optional[int]:
    """SIGTERM, then SIGKILL after `grace` seconds; the exit code (None: never started)."""
    if proc is None:
        return None
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def integration_conftest():
    """tests/integration/conftest.py as a module, for the stages that reuse its fixtures
    (tests/peers, tests/sitl): loaded once, under its own name."""
    import importlib.util
    if "integration_conftest" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "integration_conftest", Path(__file__).resolve().parent / "conftest.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules["integration_conftest"] = module
        spec.loader.exec_module(module)
    return sys.modules["integration_conftest"]


# --- the daemon ---------------------------------------------------------------------------

def parse_stats_line(line: str) -> Optional[dict]:
    m = STATS_RE.search(line)
    if not m:
        return None
    d = {"endpoint": m.group(1), "kind": m.group(2)}
    for kv in m.group(3).split():
        k, _, v = kv.partition("=")
        d[k] = int(v)
    return d


def parse_stats(text: str) -> List[dict]:
    complete = text[:text.rfind("\n") + 1]  # a line the daemon is still writing is not read
    return [d for d in (parse_stats_line(l) for l in complete.splitlines()) if d]


# What AddressSanitizer, LeakSanitizer and UBSan print (a sanitizer build: scripts/test's
# build-asan). UBSan may go on after its report, and leaks are reported only at a normal exit.
SANITIZER_REPORT_RE = re.compile(r"ERROR: AddressSanitizer|ERROR: LeakSanitizer|runtime error:")


def sanitizer_report(text: str) -> Optional[str]:
    """The first sanitizer report in a log, with some context; None when there is none."""
    m = SANITIZER_REPORT_RE.search(text)
    if m is None:
        return None
    start = text.rfind("\n", 0, max(0, m.start() - 300)) + 1
    return text[start:m.start() + 4000]


class Daemon:
    """One mavbond process with a config in `workdir`; stderr goes to a file. Every Daemon a
    test creates is listed in Daemon.created, so conftest can end it gently and fail the test
    on a sanitizer report in its log, whatever the test itself did."""

    created: List["Daemon"] = []

    def __init__(self, binary: str, workdir: Path, config_text: str, name: str = "mavbond",
                 extra_args: Iterable[str] = ("--log-level", "debug")):
        Daemon.created.append(self)
        self.binary = binary
        self.workdir = workdir
        self.config_path = workdir / f"{name}.yaml"
        self.config_path.write_text(config_text)
        self.log_path = workdir / f"{name}.log"
        self.extra_args = list(extra_args)
        self.proc: Optional[subprocess.Popen] = None
        self.returncode: Optional[int] = None
        self.endpoint_names = [n for n in re.findall(r"\{name: ([^,}]+)", config_text)]

    def start(self, wait_for: str = "running with", timeout: float = 5.0) -> "Daemon":
        self._logf = open(self.log_path, "wb")
        self.proc = subprocess.Popen([self.binary, "-c", str(self.config_path), *self.extra_args],
                                     stdin=subprocess.DEVNULL, stdout=self._logf,
                                     stderr=subprocess.STDOUT)
        self.wait_log(wait_for, timeout)
        return self

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def wait_log(self, pattern: str, timeout: float = 5.0, count: int = 1) -> str:
        """Waits until `pattern` (a regex) matches at least `count` times in the log."""
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern)
        while True:
            text = self.log()
            if len(rx.findall(text)) >= count:
                return text
            if self.proc is not None and self.proc.poll() is not None:
                raise AssertionError(f"mavbond exited with {self.proc.returncode} while waiting "
                                     f"for {pattern!r}; log:\n{text}")
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {pattern!r} in mavbond's log:\n{text}")
            time.sleep(0.02)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stats(self, timeout: float = 3.0) -> Dict[str, dict]:
        """Sends SIGUSR1 and returns {endpoint name: counters} from the lines it logged."""
        before = len(parse_stats(self.log()))
        n = len(self.endpoint_names)
        self.proc.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        while True:
            lines = parse_stats(self.log())
            if len(lines) >= before + n:
                return {d["endpoint"]: d for d in lines[before:before + n]}
            if time.monotonic() > deadline:
                raise AssertionError(f"no stats after SIGUSR1; log:\n{self.log()}")
            time.sleep(0.02)

    def settle_stats(self, key: Callable[[Dict[str, dict]], object], timeout: float = 3.0,
                     interval: float = 0.15) -> Dict[str, dict]:
        """Stats once key(stats) stopped changing between two reads."""
        deadline = time.monotonic() + timeout
        last = self.stats()
        while time.monotonic() < deadline:
            time.sleep(interval)
            cur = self.stats()
            if key(cur) == key(last):
                return cur
            last = cur
        return last

    def wait_stats(self, done: Callable[[Dict[str, dict]], bool],
                   timeout: float = 30.0) -> Dict[str, dict]:
        """Stats once done(stats) holds (the daemon took what was sent); fails with the last
        ones after `timeout`."""
        deadline = time.monotonic() + timeout
        while True:
            st = self.stats()
            if done(st):
                return st
            if time.monotonic() > deadline:
                raise AssertionError(f"the counters never got there: {st}")
            time.sleep(0.05)

    def stop(self, timeout: float = 5.0) -> int:
        """SIGTERM; returns the exit code (fails the test if it does not exit in time)."""
        if self.proc is None:
            return -1
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise AssertionError(f"mavbond did not exit {timeout}s after SIGTERM")
        self.returncode = self.proc.returncode
        self._logf.close()
        self.check_sanitizers()
        return self.returncode

    def final_stats(self) -> Dict[str, dict]:
        """The counters logged at exit (after stop())."""
        lines = parse_stats(self.log())
        n = len(self.endpoint_names)
        return {d["endpoint"]: d for d in lines[-n:]}

    def kill(self, grace: float = 5.0) -> None:
        """Ends the process whatever state it is in: SIGTERM first, so that a sanitizer build
        still checks for leaks at exit, then SIGKILL after `grace` seconds. Never raises."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None and not self._logf.closed:
            self._logf.close()

    def check_sanitizers(self) -> None:
        """Fails with the report when the log holds a sanitizer report."""
        report = sanitizer_report(self.log())
        if report is not None:
            raise AssertionError(f"sanitizer report in {self.log_path}:\n{report}")


# --- pseudo-terminals ---------------------------------------------------------------------

class Pty:
    """A pty pair: the daemon gets the slave's path, the test keeps the raw master."""

    def __init__(self):
        self.master, slave = os.openpty()
        self.path = os.ttyname(slave)
        tty.setraw(self.master)
        tty.setraw(slave)
        os.close(slave)
        os.set_blocking(self.master, False)

    def write_all(self, data: bytes, timeout: float = 10.0) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + timeout
        while view:
            try:
                n = os.write(self.master, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise AssertionError("pty write stalled")
                time.sleep(0.001)

    def read_for(self, quiet: float = 0.3, timeout: float = 5.0,
                 until: Optional[Callable[[bytes], bool]] = None) -> bytes:
        """Reads until `until(data)` is true, or nothing came for `quiet` seconds, or timeout."""
        buf = bytearray()
        deadline = time.monotonic() + timeout
        last = time.monotonic()
        while time.monotonic() < deadline:
            try:
                chunk = os.read(self.master, 65536)
                if chunk:
                    buf += chunk
                    last = time.monotonic()
                    if until is not None and until(bytes(buf)):
                        break
                    continue
            except BlockingIOError:
                pass
            except OSError:  # EIO: no slave open (yet)
                pass
            if until is None and time.monotonic() - last > quiet:
                break
            time.sleep(0.002)
        return bytes(buf)

    def close(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


def status_document(path, timeout: float = 5.0) -> dict:
    """The daemon's status socket: one JSON document, then the server closes."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(str(path))
        data = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                return json.loads(data)
            data += chunk


def split_stream(data: bytes) -> List[bytes]:
    """Frames of a raw byte stream that holds only whole frames."""
    return [r.data for r in tlog.iter_records_bytes(data, raw=True) if r.kind == "frame"]


# --- other users ----------------------------------------------------------------------------

def run_as(uid: int, gid: int, work: Callable[[], str], groups=(),
           timeout: int = 10) -> Callable[[], str]:
    """Runs work() in a forked child as uid/gid (with `groups`), at most `timeout` seconds;
    returns a function that waits for the child and returns what work() returned. (Needs
    root.)"""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        code = 1
        try:
            os.close(r)
            signal.alarm(timeout)  # bounded whatever happens
            os.setgroups(list(groups))
            os.setgid(gid)
            os.setuid(uid)
            os.write(w, work().encode())
            code = 0
        finally:
            os._exit(code)
    os.close(w)

    def result() -> str:
        with os.fdopen(r, "rb") as f:
            msg = f.read().decode()
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 0, "the child failed"
        return msg

    return result


# --- the daemon seen from /proc ------------------------------------------------------------

def rss_kib(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for {pid}")


def rss_means_memory(pid: int) -> bool:
    """False for a daemon built with AddressSanitizer: freed memory waits in its quarantine
    (256 MB) before reuse, so RSS measures ASan, not mavbond. In that build LeakSanitizer
    checks for leaks at the daemon's exit instead, and the descriptor checks still hold."""
    return "libasan" not in open(f"/proc/{pid}/maps").read()


class PtyReader(threading.Thread):
    """Reads the device side of a pty (a radio's) as fast as it comes, until stopped."""

    def __init__(self, pty):
        super().__init__(daemon=True)
        self.pty, self.data, self.stop_flag = pty, bytearray(), threading.Event()
        self.last_byte = time.monotonic()

    def run(self):
        while not self.stop_flag.is_set():
            try:
                chunk = os.read(self.pty.master, 65536)
                if chunk:
                    self.data += chunk
                    self.last_byte = time.monotonic()
                    continue
            except (BlockingIOError, OSError):
                pass
            time.sleep(0.001)


def known_defect(issue: int, what: str):
    """A test of something the product does not do right yet (issue `issue` is open on it): it
    runs and prints what it found, and is reported as an expected failure, with `what` it found
    when marked, so the rest of scripts/test can land. Every one is listed in the closing note
    of its issue; take the mark off with the fix."""
    import pytest
    return pytest.mark.xfail(reason=f"known defect, issue {issue} open: {what}", strict=False)
