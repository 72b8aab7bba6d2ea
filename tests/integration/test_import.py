"""mavbond --import-mavlink-router: realistic mavlink-router configs become YAML that equals
the reviewed expected file and that `mavbond --check-config` accepts; what has no equivalent
is a comment and a warning; malformed INI is refused with file:line and exit 65; an imported
config routes."""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest

from helpers import (HOST, Daemon, FrameMaker, free_port, recv_datagrams, split_stream, tlog,
                     udp_socket)

DATA = Path(__file__).resolve().parent / "data" / "mavlink-router"
EX_DATAERR = 65
EX_NOINPUT = 66


def run_import(binary: str, conf: Path) -> subprocess.CompletedProcess:
    # Run from the file's directory so the path in the output's first line is just its name.
    return subprocess.run([binary, "--import-mavlink-router", conf.name], cwd=conf.parent,
                          capture_output=True, text=True, timeout=30)


def check_config(binary: str, plugin_dir: str, path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([binary, "--check-config", "-c", str(path), "--plugin-dir", plugin_dir],
                          capture_output=True, text=True, timeout=30)


WARNINGS = {
    "companion": [],
    "sample": [
        "sample.conf: no TcpServerPort: mavlink-router's default TCP server listens on every "
        "address, kept as 0.0.0.0:5760",
    ],
    "redundant": [
        "redundant.conf:4: TcpServerPort = 5790 listens on every address",
        "redundant.conf:6: DeDuplicationPeriod = 200, kept as window: 200ms",
        "redundant.conf:7: Log = /var/log/flight stack: mavbond.service may write only under "
        "/var/log/mavbond",
        "redundant.conf:8: LogMode = while-armed",
        "redundant.conf:9: MaxLogFiles = 20",
        "redundant.conf:10: SnifferSysid = 254",
        "redundant.conf:14: Baud = 57600,115200",
        "redundant.conf:15: Group 'air link' is the bond 'air_link'",
        "redundant.conf:24: [UartEndpoint radio@2.4GHz] AllowSrcSysOut = 1",
        "redundant.conf:19: endpoint 'radio@2.4GHz' is named 'radio_2.4GHz'",
        "redundant.conf:38: [UdpEndpoint defaultport] has no Port",
    ],
}


@pytest.mark.parametrize("name", sorted(WARNINGS))
def test_import_matches_expected_and_checks_ok(mavbond_bin, plugin_dir, tmp_path, name):
    r = run_import(mavbond_bin, DATA / f"{name}.conf")
    assert r.returncode == 0, r.stderr
    expected = (DATA / f"{name}.yaml").read_text()
    assert r.stdout == expected, f"{name}: the imported YAML differs from {name}.yaml"
    warnings = [l for l in r.stderr.splitlines() if l.startswith("mavbond: warning: ")]
    assert len(warnings) == len(WARNINGS[name]) == len(r.stderr.splitlines()), r.stderr
    for want in WARNINGS[name]:
        assert any(want in w for w in warnings), f"no warning {want!r} in:\n{r.stderr}"
    # Everything not translated, or translated at a risk, is also a comment in the output, at
    # its line (the file as a whole: "# check: ...").
    for want in WARNINGS[name]:
        line = want.split(":")[1]
        if "is named" not in want and "is the bond" not in want:
            assert (f"(line {line})" if line.isdigit() else "# check: ") in r.stdout
    out = tmp_path / f"{name}.yaml"
    out.write_text(r.stdout)
    c = check_config(mavbond_bin, plugin_dir, out)
    print(f"\n{name}: {c.stdout.strip()}")
    assert c.returncode == 0 and c.stdout.strip().endswith(")") and ": OK (" in c.stdout, c.stderr


@pytest.mark.parametrize("text,error", [
    ("[General]\nTcpServerPort = 0\n[UdpEndpoint gcs\nMode = Server\n",
     "bad.conf:3: section header without its closing ']': [UdpEndpoint gcs"),
    ("TcpServerPort = 0\n[General]\n", "bad.conf:1: 'TcpServerPort' comes before any [section]"),
    ("[General]\n\n# comment\nTcpServerPort 5760\n",
     "bad.conf:4: expected 'Key = Value', '[Section]' or a '#' comment, got 'TcpServerPort 5760'"),
    ("[UdpEndpoint gcs]\nMode = Server\nAddress = 0.0.0.0\nPort = 99999\n",
     "bad.conf:4: Port: '99999' is not an integer in 1..65535"),
    ("[UartEndpoint fc]\nBaud = 57600\n", "bad.conf:1: [UartEndpoint fc]: missing Device"),
    ("[UdpEndpoint gcs]\nMode = Listen\nAddress = 0.0.0.0\nPort = 14550\n",
     "bad.conf:2: Mode: 'Listen' is not Normal or Server"),
    ("[UdpEndpoint gcs]\nMode = Server\nAddress = 0.0.0.0\n",
     "bad.conf:1: [UdpEndpoint gcs]: missing Port (mandatory in Server mode)"),
    ("[General]\nReportStats = yes\n", "bad.conf:2: ReportStats: 'yes' is not a boolean (true, false, 1 or 0)"),
    ("[UdpEndpoint a]\nMode=Normal\nAddress=127.0.0.1\n[udpendpoint A]\n",
     "bad.conf:4: section [udpendpoint A] repeated (first at line 1)"),
    ("[UartEndpoint fc]\nDevice = /dev/ttyS0\nAllowMsgIdOut = 0, x\n",
     "bad.conf:3: AllowMsgIdOut: 'x' is not an integer in 0..16777215"),
])
def test_malformed_ini_is_refused_with_file_and_line(mavbond_bin, tmp_path, text, error):
    conf = tmp_path / "bad.conf"
    conf.write_text(text)
    r = run_import(mavbond_bin, conf)
    assert r.returncode == EX_DATAERR
    assert r.stderr.strip() == error
    assert r.stdout == "", "nothing half-translated on stdout"


def test_what_is_copied_at_a_risk_is_said(mavbond_bin, tmp_path):
    """The three risks issue 21 (item 13) found copied silently: a dedup window shorter than a
    radio's lag behind LTE, a log directory the service may not write, and mavlink-router's
    default TCP server, which listens on every address (it binds 0.0.0.0, or [::] in its later
    versions, never loopback only): each kept or moved as said, with a warning and a comment."""
    conf = tmp_path / "main.conf"
    conf.write_text("[General]\nDeduplicationPeriod = 100\nLog = /var/log/flight-stack\n\n"
                    "[UartEndpoint fc]\nDevice = /dev/ttyS0\nGroup = air\n"
                    "[UdpEndpoint lte]\nMode = Normal\nAddress = 192.0.2.10\nPort = 14560\n"
                    "Group = air\n")
    r = run_import(mavbond_bin, conf)
    print(f"\n{r.stderr}")
    assert r.returncode == 0
    warnings = r.stderr.splitlines()
    assert len(warnings) == 3, r.stderr

    def warning(start: str) -> str:
        found = [w for w in warnings if w.startswith("mavbond: warning: " + start)]
        assert len(found) == 1, f"no warning {start!r} in:\n{r.stderr}"
        return found[0]

    assert ("mavbond.service may write only under /var/log/mavbond, so the flight logs go there"
            in warning("main.conf:3: Log = /var/log/flight-stack: "))
    assert ("listens on every address, kept as 0.0.0.0:5760: anyone who can reach this machine "
            "may connect and command the vehicle; use 127.0.0.1:5760"
            in warning("main.conf:1: no TcpServerPort: mavlink-router's default TCP server"))
    dedup = warning("main.conf:2: DeDuplicationPeriod = 100, kept as window: 100ms: ")
    assert "a copy that comes later than that over another link is delivered twice" in dedup
    assert "use window: 2s for radio + LTE" in dedup
    assert "directory: /var/log/mavbond\n" in r.stdout and "window: 100ms" in r.stdout
    assert r.stdout.count("# check") == 3


def test_missing_file(mavbond_bin, tmp_path):
    r = run_import(mavbond_bin, tmp_path / "nope.conf")
    assert r.returncode == EX_NOINPUT and "nope.conf: cannot open" in r.stderr


def test_imported_config_routes_and_deduplicates(mavbond_bin, plugin_dir, tmp_path):
    """Two radios in one Group with DeDuplicationPeriod: each frame sent over both reaches the
    GCS once, complete and in order."""
    in_a, in_b, out_port = free_port(), free_port(), free_port()
    conf = tmp_path / "main.conf"
    conf.write_text(f"""[General]
TcpServerPort = 0
DeDuplicationPeriod = 500

[UdpEndpoint radioA]
Mode = Server
Address = 127.0.0.1
Port = {in_a}
Group = radios

[UdpEndpoint radioB]
Mode = Server
Address = 127.0.0.1
Port = {in_b}
Group = radios

[UdpEndpoint gcs]
Mode = Normal
Address = 127.0.0.1
Port = {out_port}
""")
    r = run_import(mavbond_bin, conf)
    # The one thing said: the window is short beside a radio's lag behind LTE.
    assert r.returncode == 0 and len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith("mavbond: warning: main.conf:3: DeDuplicationPeriod = 500, kept as "
                               "window: 500ms"), r.stderr
    assert "plugin: dedup" in r.stdout and "window: 500ms" in r.stdout
    d = Daemon(mavbond_bin, tmp_path, r.stdout, name="imported",
               extra_args=["--plugin-dir", plugin_dir, "--log-level", "debug"])
    gcs, radio_a, radio_b = udp_socket(out_port), udp_socket(), udp_socket()
    try:
        d.start()
        vm = FrameMaker(1, 1, counting=True)  # an autopilot numbers its frames
        frames = vm.telemetry(30)
        for f in frames:
            radio_a.sendto(f, (HOST, in_a))
            radio_b.sendto(f, (HOST, in_b))
            time.sleep(0.005)
        got = [f for dg in recv_datagrams(gcs, None, timeout=5, quiet=0.5) for f in split_stream(dg)]
        print(f"\nsent {len(frames)} frames over two radios, the GCS got {len(got)}")
        # The bond renumbers what dedup delivers (derived: a GCS counts as lost only what every
        # link lost), so a frame is known by its content; the numbers are one gapless count.
        content = lambda f: (tlog.sysid(f), tlog.compid(f), tlog.msgid(f), tlog.payload(f))
        assert [content(f) for f in got] == [content(f) for f in frames], \
            "every frame routed once: the imported dedup dropped the copies"
        seqs = [tlog.seq(f) for f in got]
        assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:])), str(seqs)
    finally:
        gcs.close()
        radio_a.close()
        radio_b.close()
        d.kill()
