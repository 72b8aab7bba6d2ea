"""The command line and the config file: --check-config on the shipped files, exit 78 with
file:line:column for malformed configs, clean exit on SIGTERM/SIGINT."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from helpers import REPO, Daemon, free_port, make_config, tcp_client, uart, udp_server

SHIPPED = [REPO / "conf" / "mavbond.yaml", *sorted((REPO / "conf" / "examples").glob("*.yaml"))]


SHIPPED_KEY = "/etc/mavbond/bond.key"  # the examples' signed bond's key file


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: str(p.relative_to(REPO)))
def test_check_config_shipped_files(mavbond_bin, plugin_dir, path, tmp_path):
    # The examples name the plugins: they are loaded (and their options checked) too. Their
    # bond's key file is made here, as `mavbondctl keygen` makes it (the only change).
    text = path.read_text()
    if SHIPPED_KEY in text:
        key = tmp_path / "bond.key"
        subprocess.run([str(Path(mavbond_bin).parent / "mavbondctl"), "keygen", str(key)],
                       check=True, capture_output=True)
        path = tmp_path / path.name
        path.write_text(text.replace(SHIPPED_KEY, str(key)))
    r = subprocess.run([mavbond_bin, "--check-config", "-c", str(path), "--plugin-dir", plugin_dir],
                       capture_output=True, text=True, timeout=10)
    print(f"\n{path.name}: exit {r.returncode}: {r.stdout.strip()} {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr


# (config text, 1-based line the error must point at, a word the message must contain)
MALFORMED = [
    ("endpoints:\n  - {name: a, type: udp, mode: server, address: 127.0.0.1:1, colour: red}\n",
     2, "colour"),
    ("log_level: info\nendpoints:\n  - name: a\n    type: uart\n    device: /dev/null\n"
     "    reconnect_min: 100\n", 6, "unit"),
    ("log_level: loud\nendpoints:\n  - {name: a, type: udp, mode: server, address: 127.0.0.1:1}\n",
     1, "log_level"),
    ("endpoints:\n  - {name: a, type: udp, mode: server, address: 127.0.0.1:1}\n"
     "  - {name: a, type: udp, mode: server, address: 127.0.0.1:2}\n", 3, "duplicate"),
    ("endpoints:\n  - {name: a, type: udp, mode: server, address: 127.0.0.1:1,\n"
     "     block_out: [NOT_A_MESSAGE]}\n", 3, "NOT_A_MESSAGE"),
    ("unknown_messages: forward\nendpoints: [\n", None, ""),  # YAML syntax error
    ("unknown_messages: keep\nendpoints:\n  - {name: a, type: udp, mode: server, "
     "address: 127.0.0.1:1}\n", 1, "keep"),
]


@pytest.mark.parametrize("text,line,word", MALFORMED, ids=[f"case{i}" for i in range(len(MALFORMED))])
@pytest.mark.parametrize("check", [True, False], ids=["check-config", "run"])
def test_malformed_config_exit_78(mavbond_bin, tmp_path, text, line, word, check):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    args = [mavbond_bin, "-c", str(path)] + (["--check-config"] if check else [])
    r = subprocess.run(args, capture_output=True, text=True, timeout=10)
    print(f"\nexit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == 78
    m = re.search(rf"^{re.escape(str(path))}:(\d+):(\d+): (.+)$", r.stderr, re.M)
    assert m, f"no file:line:column: message on stderr: {r.stderr!r}"
    if line is not None:
        assert int(m.group(1)) == line, r.stderr
    assert word in m.group(3)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_clean_exit(mavbond_bin, tmp_path, sig):
    # with retry timers pending: a missing UART and a TCP client with nobody to connect to
    d = Daemon(mavbond_bin, tmp_path, make_config([
        udp_server("gcs", free_port()),
        uart("u", str(tmp_path / "ttyNONE"), reconnect_min="100ms", reconnect_max="200ms"),
        tcp_client("tc", free_port(socket.SOCK_STREAM), reconnect_min="100ms",
                   reconnect_max="200ms")]))
    try:
        d.start()
        time.sleep(0.3)
        t0 = time.monotonic()
        d.proc.send_signal(sig)
        code = d.proc.wait(timeout=1.0)
        took = time.monotonic() - t0
        print(f"\n{sig.name}: exit {code} after {took * 1000:.0f} ms")
        assert code == 0
        assert took < 1.0
        log = d.log()
        assert "stats endpoint=gcs kind=udp-server" in log, "counters are logged at exit"
    finally:
        d.kill()


def test_sigusr1_logs_stats_and_keeps_running(start_daemon):
    d = start_daemon([udp_server("a", free_port()), udp_server("b", free_port())])
    st = d.stats()
    print("\n", st)
    assert set(st) == {"a", "b"} and all(s["rx_frames"] == 0 for s in st.values())
    assert d.alive()
    assert d.stop() == 0
