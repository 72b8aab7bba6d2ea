"""mavbondctl watch against a real daemon with traffic: one line per link with its bond,
state, loss (from the stats filter, and what it is read from), receive rate, time since its
last frame and the active-link marker, one line per bond; one block per refresh through a
pipe, redrawn in place on a terminal, no line past 80 columns."""
from __future__ import annotations

import os
import pty
import re
import subprocess
import threading
import time
from pathlib import Path
from typing import Dict, List

from bonding_helpers import Gateway
from helpers import HOST, FrameMaker, free_port, udp_server, udp_socket

ROW = re.compile(r"^(?P<mark>[* ]) (?P<name>\S+)\s+(?P<bond>\S+)\s+(?P<state>\S+)\s+"
                 r"(?P<loss>\S+)\s+(?P<by>\S+)\s+(?P<rate>\S+)\s+(?P<ago>\S+)$")
BOND = re.compile(r"^  bond (?P<name>\S+): (?P<figures>.*)$")


def ctl_bin(mavbond_bin: str) -> str:
    return str(Path(mavbond_bin).with_name("mavbondctl"))


def parse_blocks(text: str) -> List[Dict[str, dict]]:
    blocks = []
    for chunk in text.strip().split("\n\n"):
        lines = chunk.splitlines()
        assert lines[0].startswith("mavbond ") and "LINK" in lines[1], chunk
        rows = {}
        last = None
        for line in lines[2:]:
            assert len(line) <= 80, f"past 80 columns: {line!r}"
            if line.startswith("    "):  # under a link: its budget, its radio
                last.setdefault("sub", []).append(line)
                continue
            if b := BOND.match(line):
                rows["bond " + b["name"]] = last = b.groupdict()
                continue
            m = ROW.match(line)
            assert m, f"unexpected line {line!r}"
            rows[m["name"]] = last = m.groupdict()
        blocks.append(rows)
    return blocks


def seconds(ago: str) -> float:
    assert ago.endswith("s") and "m" not in ago, ago
    return float(ago[:-1])


def start_gateway(mavbond_bin, plugin_dir, tmp_path, ports):
    sock = tmp_path / "status.sock"
    gw = Gateway(mavbond_bin, tmp_path,
                 [udp_server("radioA", ports[0], bond="air"), udp_server("radioB", ports[1], bond="air"),
                  udp_server("gcs", ports[2], tx_rate="1MB/s")],
                 bonds=[{"name": "air", "tx": "active"}],
                 # dedup first: its status lists the links by the same names, without a loss
                 # (watch read its entry once and showed 0.00%)
                 filters=[{"plugin": "dedup", "bonds": ["air"]},
                          {"plugin": "linkswitch", "bonds": ["air"]}, {"plugin": "stats"}],
                 plugin_dir=plugin_dir, status_socket=str(sock))
    return gw.start(), sock


def test_watch_through_a_pipe(mavbond_bin, plugin_dir, tmp_path):
    ports = [free_port(), free_port(), free_port()]
    gw, sock = start_gateway(mavbond_bin, plugin_dir, tmp_path, ports)
    radio_a, radio_b, gcs = udp_socket(), udp_socket(), udp_socket()
    vm = FrameMaker(1, 1)
    stop = threading.Event()

    def vehicle():
        # ~50 frames/s over radio A; every 10th frame is never sent: 10% loss by sequence.
        i = 0
        deadline = time.monotonic() + 15
        while not stop.is_set() and time.monotonic() < deadline:
            vm.mav.seq = i % 256  # pymavlink's pack() alone leaves the sequence alone
            f = vm.attitude(i)
            if i % 10 != 9:
                radio_a.sendto(f, (HOST, ports[0]))
            i += 1
            time.sleep(0.02)

    try:
        gcs.sendto(FrameMaker(255, 190).heartbeat(6), (HOST, ports[2]))
        radio_b.sendto(FrameMaker(1, 1).heartbeat(), (HOST, ports[1]))  # once, then silent
        sender = threading.Thread(target=vehicle)
        sender.start()
        time.sleep(1.0)
        r = subprocess.run([ctl_bin(mavbond_bin), "-s", str(sock), "watch", "--interval", "0.5",
                            "--count", "5"], capture_output=True, text=True, timeout=60)
    finally:
        stop.set()
        sender.join(timeout=5)
        for s in (radio_a, radio_b, gcs):
            s.close()
    print("\n" + r.stdout)
    assert r.returncode == 0, r.stderr
    assert "\033[" not in r.stdout, "no terminal codes into a pipe"
    blocks = parse_blocks(r.stdout)
    assert len(blocks) == 5
    assert set(blocks[0]) == {"radioA", "radioB", "gcs", "bond air"}
    assert all(row["rate"] == "-" for name, row in blocks[0].items() if name != "bond air"), \
        "no rate before two samples"
    last = blocks[-1]
    a, b, g = last["radioA"], last["radioB"], last["gcs"]
    assert (a["bond"], b["bond"], g["bond"]) == ("air", "air", "-")
    assert a["mark"] == "*" and b["mark"] == " " and g["mark"] == " ", "radio A is the active link"
    rate_a = float(a["rate"])
    assert 10 <= rate_a <= 150, f"radio A carries about 45 frames/s, watch says {rate_a}"
    assert float(b["rate"]) == 0.0
    assert 5.0 <= float(a["loss"].rstrip("%")) <= 15.0, f"10% of radio A's frames were never sent: {a}"
    # Its far side (the test) sends no count markers: the loss is read from sequence gaps.
    assert a["by"] == "sequence"
    # Radio A is heard, radio B spoke once (down), the GCS is no bond member (up).
    assert (a["state"], b["state"], g["state"]) == ("up", "down", "up")
    # The GCS's budget: one line per class at most, wrapped between classes, never in one.
    budget = g["sub"]
    assert budget[0].startswith("    tx 1000000 B/s; control ") and len(budget) >= 2, budget
    for line, following in zip(budget, budget[1:]):
        assert line.endswith(";") and following.startswith("       ") and \
            re.match(r"^ {7}(telemetry|bulk) ", following), budget
    assert budget[-1].endswith("thinned or dropped)"), budget
    assert re.fullmatch(r"delivered loss \d+\.\d\d% \(\d+ of \d+ lost\); active link radioA",
                        last["bond air"]["figures"]), last["bond air"]
    assert seconds(a["ago"]) < 1.0, "radio A is heard all the time"
    assert seconds(b["ago"]) >= 1.0, "radio B spoke once, more than a second ago"
    assert seconds(b["ago"]) > seconds(blocks[0]["radioB"]["ago"]), "last heard grows while silent"
    gw.stop()


def test_watch_on_a_terminal_redraws_in_place(mavbond_bin, plugin_dir, tmp_path):
    ports = [free_port(), free_port(), free_port()]
    gw, sock = start_gateway(mavbond_bin, plugin_dir, tmp_path, ports)
    master, slave = pty.openpty()
    try:
        p = subprocess.Popen([ctl_bin(mavbond_bin), "-s", str(sock), "watch", "--interval", "0.2",
                              "--count", "3"], stdout=slave, stderr=subprocess.PIPE)
        os.close(slave)
        out = b""
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: mavbondctl exited and closed the terminal
                break
            if not chunk:
                break
            out += chunk
        assert p.wait(timeout=20) == 0
    finally:
        os.close(master)
    text = out.decode()
    assert text.count("\033[H\033[2J") == 3, "each refresh clears the screen and starts at the top"
    assert text.count("LINK") == 3 and "\n\n" not in text.replace("\r", "")
    gw.stop()


def test_watch_errors(mavbond_bin, tmp_path):
    ctl = ctl_bin(mavbond_bin)
    r = subprocess.run([ctl, "-s", str(tmp_path / "none.sock"), "watch", "--count", "1"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 69 and "cannot connect" in r.stderr
    r = subprocess.run([ctl, "watch", "--interval", "0"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 64 and "--interval" in r.stderr
    r = subprocess.run([ctl, "watch", "--count", "x"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 64 and "--count" in r.stderr
