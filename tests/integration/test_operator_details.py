"""What an operator meets (issue 21, item 14), against the real binaries: mavbondctl names an
unknown command before its usage; log lines carry the time unless stderr is the journal's
stream (JOURNAL_STREAM); the stats filter logs no line per interval unless told to; counts
read "1 endpoint", not "1 endpoints"; and mavbond's own frames reach every receiver as a
gapless stream: its standby reports, which go to a bond's links only, leave no gap at the GCS,
and a bond's links get one stream (the same numbers on each)."""
from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

from bonding_helpers import Gateway, Receiver, Ticker, tlog, udp_sock
from helpers import HOST, FrameMaker, free_port, udp_client, udp_server

TIMESTAMP = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} mavbond: "


def mavbondctl(mavbond_bin: str) -> str:
    return str(Path(mavbond_bin).parent / "mavbondctl")


def test_mavbondctl_names_an_unknown_command(mavbond_bin, tmp_path):
    r = subprocess.run([mavbondctl(mavbond_bin), "stat"], capture_output=True, text=True, timeout=10)
    print(f"\nexit {r.returncode}:\n{r.stderr}")
    assert r.returncode == 64
    lines = r.stderr.splitlines()
    assert lines[0] == "mavbondctl: unknown command 'stat' (status or watch)"
    assert lines[1].startswith("Usage: mavbondctl")
    r = subprocess.run([mavbondctl(mavbond_bin)], capture_output=True, text=True, timeout=10)
    assert r.returncode == 64 and r.stderr.startswith("mavbondctl: no command given (status or watch)\n")
    r = subprocess.run([mavbondctl(mavbond_bin), "status", "now"], capture_output=True, text=True,
                       timeout=10)
    assert r.returncode == 64 and r.stderr.startswith("mavbondctl: unexpected argument 'now' after status\n")


def run_briefly(mavbond_bin, tmp_path: Path, log: Path, env: dict, journal: bool = False) -> list:
    """Starts mavbond with stderr to `log` until it runs, stops it; the log's lines. With
    `journal`, JOURNAL_STREAM names that very file, as systemd names its stream."""
    cfg = tmp_path / "m.yaml"
    cfg.write_text(f"endpoints:\n  - {{name: gcs, type: udp, mode: server, address: {HOST}:{free_port()}}}\n")
    with open(log, "w") as f:
        if journal:
            st = os.fstat(f.fileno())
            env = dict(env, JOURNAL_STREAM=f"{st.st_dev}:{st.st_ino}")
        p = subprocess.Popen([mavbond_bin, "-c", str(cfg)], stdout=subprocess.DEVNULL, stderr=f,
                             env=env)
        try:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and "running with" not in log.read_text():
                time.sleep(0.05)
        finally:
            p.terminate()
            assert p.wait(10) == 0
    return log.read_text().splitlines()


def test_log_lines_carry_the_time_unless_stderr_is_the_journal(mavbond_bin, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    plain = run_briefly(mavbond_bin, tmp_path, tmp_path / "plain.log", env)
    # JOURNAL_STREAM naming another stream (inherited from a service that started us with
    # stderr elsewhere): a file all the same, stamped.
    inherited = run_briefly(mavbond_bin, tmp_path, tmp_path / "inherited.log",
                            dict(env, JOURNAL_STREAM="1:1"))
    # JOURNAL_STREAM naming this very stderr: journald stamps it, the daemon writes <N>.
    journal = run_briefly(mavbond_bin, tmp_path, tmp_path / "journal.log", env, journal=True)
    print(f"\nby hand: {plain[0]}\ninherited: {inherited[0]}\njournal: {journal[0]}")
    for lines in (plain, inherited):
        assert lines and all(re.match(TIMESTAMP + r"(notice|info|warning|debug): ", l) for l in lines), lines
    assert any("running with 1 endpoint from" in l for l in plain)
    assert journal and all(re.match(r"<\d>", l) for l in journal), journal


def test_stats_logs_no_line_per_interval_unless_told(mavbond_bin, plugin_dir, tmp_path):
    lines = {}
    for log in (None, True):
        csv = tmp_path / f"stats-{log}.csv"
        stats = {"plugin": "stats", "interval": "100ms", "csv": str(csv)}
        if log is not None:
            stats["log"] = "true"
        port = free_port()
        gw = Gateway(mavbond_bin, tmp_path, [udp_server("gcs", port)], filters=[stats],
                     plugin_dir=plugin_dir, name=f"stats-{log}").start()
        src = udp_sock()
        vm = FrameMaker(1, 1)
        # The CSV gets a row per interval: 10 intervals are the evidence, not the clock.
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            src.sendto(vm.heartbeat(), (HOST, port))
            if csv.exists() and len(csv.read_text().splitlines()) > 10:
                break
            time.sleep(0.05)
        assert gw.stop() == 0
        src.close()
        rows = len(csv.read_text().splitlines()) - 1
        lines[log] = (rows, [l for l in gw.log().splitlines() if "[filter:stats] gcs@" in l])
    print(f"\ndefault: {lines[None][0]} intervals, {len(lines[None][1])} lines; "
          f"log: true: {lines[True][0]} intervals, {len(lines[True][1])} lines")
    assert lines[None][0] >= 10 and lines[None][1] == []
    assert lines[True][0] >= 10 and len(lines[True][1]) >= 5


def test_own_frames_reach_every_receiver_gapless(mavbond_bin, plugin_dir, tmp_path):
    ports = {k: free_port() for k in ("gcs", "radio", "lte")}
    gw = Gateway(mavbond_bin, tmp_path,
                 [udp_server("gcs", ports["gcs"]),
                  udp_server("radio", ports["radio"], bond="vehicle"),
                  udp_server("lte", ports["lte"], bond="vehicle", cost="metered")],
                 bonds=[{"name": "vehicle"}], plugin_dir=plugin_dir,
                 identity="{sysid: 42, compid: 191, heartbeat: 200ms}").start()
    socks = {k: udp_sock() for k in ports}
    vm = FrameMaker(1, 1)
    # The links' far ends send (so the servers learn them) and receive what mavbond sends down.
    tickers = [Ticker(socks[k], (HOST, ports[k]), lambda _: vm.heartbeat(), 0.1)
               for k in ("radio", "lte")]
    rx = {k: Receiver(socks[k]) for k in ("radio", "lte")}
    rx["gcs"] = Receiver(socks["gcs"], hello_port=ports["gcs"])

    def own(name):
        """mavbond's own stream to `name`; the count markers a bond member writes itself (with
        a counter of the link's own, LINK ACCOUNTING) apart."""
        return [f for _, f in list(rx[name].frames)
                if tlog.sysid(f) == 42 and tlog.count_marker(f) is None]

    def markers(name):
        return [f for _, f in list(rx[name].frames)
                if tlog.sysid(f) == 42 and tlog.count_marker(f) is not None]

    try:
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            reports = [f for f in own("radio") if tlog.msgid(f) == 252]
            if len(reports) >= 3 and len(own("gcs")) >= 10:
                break
            time.sleep(0.05)
    finally:
        for t in tickers:
            t.stop()
        # The daemon stops first: once it exited, all it sent is in the receivers' sockets, so
        # each link has every frame the other has.
        rc = gw.stop()
        for r in rx.values():
            r.stop()
        assert rc == 0
    seqs = {k: [tlog.seq(f) for f in own(k)] for k in rx}
    kinds = {k: sorted({tlog.msgid(f) for f in own(k)}) for k in rx}
    print(f"\nmessage ids: {kinds}\n" + "\n".join(f"{k}: {v}" for k, v in seqs.items()))
    assert kinds["gcs"] == [0] and kinds["radio"] == kinds["lte"] == [0, 252]
    for k, s in seqs.items():
        assert len(s) >= 10, k
        assert all((b - a) % 256 == 1 for a, b in zip(s, s[1:])), f"{k}: gaps in {s}"
    # One stream on the bond: a frame has one number on every link.
    assert seqs["radio"][-8:] == seqs["lte"][-8:]
    # Each link's count markers: a gapless counter of the link's own.
    for k in ("radio", "lte"):
        m = [tlog.seq(f) for f in markers(k)]
        assert len(m) >= 2 and all((b - a) % 256 == 1 for a, b in zip(m, m[1:])), f"{k}: {m}"
    for s in socks.values():
        s.close()
