"""What systemd hears from the daemon (sd_notify's protocol on $NOTIFY_SOCKET), read from a
real AF_UNIX datagram socket as systemd reads it: READY=1 once the endpoints route, RELOADING=1
with MONOTONIC_USEC and READY=1 again around every reload (a refused one too), STOPPING=1 at
SIGTERM, WATCHDOG=1 from the loop (none while the daemon is frozen), and a STATUS= line with
each bond's links up and its delivered loss (issue 21, item 4). The booted-container test is
tests/package/systemd-test.sh."""
from __future__ import annotations

import os
import re
import signal
import socket
import time
from pathlib import Path
from typing import List, Optional

import pytest

from bonding_helpers import Gateway
from helpers import (HOST, FrameMaker, free_port, recv_datagrams, status_document, udp_client,
                     udp_server, udp_socket)


class NotifySocket:
    """systemd's end: a datagram socket the daemon is pointed at."""

    def __init__(self, path: Path):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.path = path

    def next(self, want: str, timeout: float = 5.0) -> str:
        """The next message holding `want`, skipping WATCHDOG=1 (unless that is wanted)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                msg = self.sock.recv(4096).decode()
            except socket.timeout:
                break
            if want in msg:
                return msg
        raise AssertionError(f"no {want!r} from the daemon within {timeout}s")

    def all_for(self, seconds: float) -> List[str]:
        out = []
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                out.append(self.sock.recv(4096).decode())
            except socket.timeout:
                break
        return out


@pytest.fixture
def notify(tmp_path, monkeypatch):
    s = NotifySocket(tmp_path / "notify.sock")
    monkeypatch.setenv("NOTIFY_SOCKET", str(s.path))
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # fed every 200 ms
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    yield s
    s.sock.close()


def status_of(msg: str) -> Optional[str]:
    m = re.search(r"^STATUS=(.*)$", msg, re.M)
    return m.group(1) if m else None


def test_ready_after_the_endpoints_route_then_reload_and_stop(mavbond_bin, plugin_dir, tmp_path,
                                                              notify):
    ports = {k: free_port() for k in ("a", "b", "out")}
    out = udp_socket(ports["out"])
    gw = Gateway(mavbond_bin, tmp_path,
                 [udp_server("a", ports["a"], bond="air"), udp_server("b", ports["b"], bond="air"),
                  udp_client("out", ports["out"])],
                 bonds=[{"name": "air"}],
                 filters=[{"plugin": "dedup", "bonds": ["air"]}, {"plugin": "stats"}],
                 plugin_dir=plugin_dir, status_socket=str(tmp_path / "status.sock"))
    gw.start()
    ready = notify.next("READY=1")
    # Ready means routing: a frame sent now goes through.
    vm = FrameMaker(1, 1)
    src = udp_socket()
    frames = vm.telemetry(20)
    for f in frames:
        src.sendto(f, (HOST, ports["a"]))
    got = recv_datagrams(out, len(frames), timeout=5)
    print(f"\nREADY: {ready!r}; then {len(got)} of {len(frames)} frames routed")
    assert len(got) == len(frames)
    assert status_of(ready) == "bond air: 0 of 2 links up; 3 endpoints, 0 frames routed"

    # A reload: RELOADING=1 (MONOTONIC_USEC: when it began) then READY=1 with the status now.
    before_us = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    gw.proc.send_signal(signal.SIGHUP)
    reloading = notify.next("RELOADING=1")
    after_reload = notify.next("READY=1")
    usec = int(re.search(r"^MONOTONIC_USEC=(\d+)$", reloading, re.M).group(1))
    print(f"RELOADING: {reloading!r}; READY: {after_reload!r}")
    assert before_us <= usec <= time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    # The links heard, and the delivered loss as the stats filter counts it (its own figure,
    # read from the status socket).
    m = re.fullmatch(r"bond air: 1 of 2 links up, delivered loss (\d+\.\d\d)%; 3 endpoints, "
                     r"20 frames routed", status_of(after_reload))
    assert m, after_reload
    stats = next(f for f in status_document(tmp_path / "status.sock")["filters"] if f["plugin"] == "stats")
    bond = next(b for b in stats["status"]["bonds"] if b["name"] == "air")
    assert float(m.group(1)) == round(bond["delivered_loss_pct"], 2)
    # A refused reload: systemd hears READY=1 all the same (the running config stays).
    gw.config_path.write_text("endpoints: [\n")
    gw.proc.send_signal(signal.SIGHUP)
    notify.next("RELOADING=1")
    assert "READY=1" in notify.next("READY=1")
    gw.wait_log("reload refused")

    gw.proc.send_signal(signal.SIGTERM)
    stopping = notify.next("STOPPING=1")
    assert gw.proc.wait(5) == 0
    print(f"STOPPING: {stopping!r}")
    src.close()
    out.close()


def test_the_watchdog_is_fed_by_the_loop_and_starves_when_it_is_frozen(mavbond_bin, tmp_path,
                                                                       notify):
    gw = Gateway(mavbond_bin, tmp_path, [udp_server("gcs", free_port())])
    gw.start()
    notify.next("READY=1")
    gw.wait_log(r"systemd watchdog: fed every 200ms")
    for _ in range(3):
        notify.next("WATCHDOG=1", timeout=2)
    os.kill(gw.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(0.3)  # what was on its way arrives
        notify.all_for(0.05)
        frozen = notify.all_for(1.0)  # 5 periods frozen: a fed watchdog would have had 5
    finally:
        os.kill(gw.proc.pid, signal.SIGCONT)
    resumed = notify.next("WATCHDOG=1", timeout=2)
    print(f"\nwhile frozen for 1 s: {frozen}; after SIGCONT: {resumed!r}")
    assert frozen == []
    assert gw.stop() == 0


def test_without_notify_socket_nothing_is_sent(mavbond_bin, tmp_path, monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.setenv("WATCHDOG_USEC", "400000")
    gw = Gateway(mavbond_bin, tmp_path, [udp_server("gcs", free_port())])
    gw.start()
    log = gw.log()
    assert gw.stop() == 0
    assert "systemd" not in log
