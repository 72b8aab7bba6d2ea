"""MAVLink 2 signing on an endpoint (`signing: {key_file, require: true}`): pymavlink peers
with the right key, a wrong key and none send COMMAND_LONG through it; only the correctly
signed frames come out, byte-identical, the rest are counted; a captured datagram replayed
(from the same address or another) is rejected. Bad key files are config errors (exit 78)."""
from __future__ import annotations

import os
import re
import secrets
import socket
import subprocess
import time

import pytest
from pymavlink import mavutil

from helpers import HOST, Daemon, free_port, mav2, recv_datagrams, split_stream, udp_socket

KEY_COUNTERS = ("sig_unsigned", "sig_bad", "sig_replay")


def write_key(path, key: bytes, mode=0o600, hex_form=True):
    path.write_bytes((key.hex() + "\n").encode() if hex_form else key)
    os.chmod(path, mode)
    return path


def signing_config(in_port: int, out_port: int, key_file, require="true", extra="") -> str:
    return (f"report_interval: 1s\n{extra}endpoints:\n"
            f"  - name: lte\n    type: udp\n    mode: server\n    address: {HOST}:{in_port}\n"
            f"    signing:\n      key_file: {key_file}\n      require: {require}\n"
            f"  - {{name: out, type: udp, mode: client, address: {HOST}:{out_port}}}\n")


def peer(port: int, key=None, link_id=0, sysid=255):
    """A pymavlink connection sending to the daemon; signing with `key` when given."""
    conn = mavutil.mavlink_connection(f"udpout:{HOST}:{port}", source_system=sysid,
                                      source_component=190)
    # MAVLink 2 for this connection only (mavutil's protocol choice is process-wide).
    conn.mav = mav2.MAVLink(conn, srcSystem=sysid, srcComponent=190)
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return conn


def send_command(conn, command: int) -> bytes:
    """Sends one COMMAND_LONG to system 1; returns the bytes pymavlink put on the wire."""
    msg = conn.mav.command_long_encode(1, 1, command, 0, 1, 0, 0, 0, 0, 0, 0)
    conn.mav.send(msg)
    return bytes(msg.get_msgbuf())


def test_only_correctly_signed_frames_pass(mavbond_bin, tmp_path):
    key = secrets.token_bytes(32)
    key_file = write_key(tmp_path / "lte.key", key)
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = Daemon(mavbond_bin, tmp_path, signing_config(in_port, out_port, key_file)).start()
    good = peer(in_port, key, link_id=1)
    wrong = peer(in_port, secrets.token_bytes(32), link_id=1)
    unsigned = peer(in_port)
    sent_good, n_wrong, n_unsigned = [], 0, 0
    try:
        for i in range(30):
            sent_good.append(send_command(good, 400 + i))
            assert sent_good[-1][2] & 0x01, "pymavlink signed it"
            if i % 3 == 0:
                assert send_command(wrong, 21)[2] & 0x01  # MAV_CMD_NAV_LAND, signed wrongly
                n_wrong += 1
            if i % 2 == 0:
                assert not send_command(unsigned, 21)[2] & 0x01
                n_unsigned += 1
        got = [f for dg in recv_datagrams(rx, len(sent_good), timeout=5) for f in split_stream(dg)]
        # Replays of a captured good datagram: from the same peer's address, and from another
        # (a new UDP peer of the same endpoint shares the endpoint's stream table).
        captured = sent_good[5]
        good.write(captured)
        other = udp_socket()
        other.sendto(captured, (HOST, in_port))
        other.sendto(sent_good[-1], (HOST, in_port))
        # A last good frame, after the replays: the link still works, and it marks the end.
        sent_good.append(send_command(good, 499))
        got += [f for dg in recv_datagrams(rx, 1, timeout=5) for f in split_stream(dg)]
        extra = recv_datagrams(rx, None, quiet=0.5, timeout=2)
        st = d.settle_stats(lambda s: tuple(s["lte"][k] for k in KEY_COUNTERS))
        report = d.wait_log(r"\[lte\] .*replayed or stale signed frames dropped", timeout=5)
        other.close()
    finally:
        rx.close()
        for c in (good, wrong, unsigned):
            c.close()
    lte = st["lte"]
    print(f"\nsent {len(sent_good)} signed ok, {n_wrong} wrong key, {n_unsigned} unsigned, 3 "
          f"replays; got {len(got)} (+{len(extra)} extra); counters "
          f"{ {k: lte[k] for k in KEY_COUNTERS} }")
    assert got == sent_good, "exactly the correctly signed frames, byte-identical, in order"
    assert extra == []
    assert lte["sig_bad"] == n_wrong
    assert lte["sig_unsigned"] == n_unsigned
    assert lte["sig_replay"] == 3
    assert lte["rx_frames"] == len(sent_good) + n_wrong + n_unsigned + 3
    line = [l for l in report.splitlines() if "[lte]" in l and "signed" in l][-1]
    print(f"problem report: {line.strip()}")
    assert d.stop() == 0


def test_require_false_lets_unsigned_through_but_not_bad_signatures(mavbond_bin, tmp_path):
    key = secrets.token_bytes(32)
    key_file = write_key(tmp_path / "k.bin", key, hex_form=False)  # 32 raw bytes
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = Daemon(mavbond_bin, tmp_path, signing_config(in_port, out_port, key_file, "false")).start()
    good, wrong, unsigned = peer(in_port, key), peer(in_port, secrets.token_bytes(32)), peer(in_port)
    try:
        sent = [send_command(good, 400), send_command(unsigned, 401)]
        send_command(wrong, 402)
        sent.append(send_command(good, 403))
        got = [f for dg in recv_datagrams(rx, len(sent), timeout=5) for f in split_stream(dg)]
        got += [f for dg in recv_datagrams(rx, None, quiet=0.5, timeout=2) for f in split_stream(dg)]
        st = d.settle_stats(lambda s: tuple(s["lte"][k] for k in KEY_COUNTERS))["lte"]
    finally:
        rx.close()
        for c in (good, wrong, unsigned):
            c.close()
    print(f"\nrequire false: got {len(got)}/{len(sent)}; counters { {k: st[k] for k in KEY_COUNTERS} }")
    assert got == sent
    assert (st["sig_unsigned"], st["sig_bad"], st["sig_replay"]) == (1, 1, 0)
    assert d.stop() == 0


BAD_KEYS = [
    # (file name, content, mode, a phrase of the message)
    ("open.key", b"ab" * 32, 0o644, "group or others may access it (mode 0644)"),
    ("group.key", b"ab" * 32, 0o640, "group or others may access it (mode 0640)"),
    ("short.key", b"\x01" * 31, 0o600, "holds 31 bytes: a key is 32 raw bytes or 64 hex digits"),
    ("badhex.key", b"zz" + b"ab" * 31, 0o600, "'z' at offset 0 is not a hex digit"),
    ("missing.key", None, 0o600, "cannot open: No such file or directory"),
]


@pytest.mark.parametrize("name,content,mode,phrase", BAD_KEYS, ids=[b[0] for b in BAD_KEYS])
@pytest.mark.parametrize("check", [True, False], ids=["check-config", "run"])
def test_bad_key_file_is_a_config_error(mavbond_bin, tmp_path, name, content, mode, phrase, check):
    key_file = tmp_path / name
    if content is not None:
        key_file.write_bytes(content)
        os.chmod(key_file, mode)
    config = tmp_path / "bad.yaml"
    # A relative key_file is read from the config file's directory.
    config.write_text(signing_config(free_port(), free_port(), name))
    args = [mavbond_bin, "-c", str(config)] + (["--check-config"] if check else [])
    r = subprocess.run(args, capture_output=True, text=True, timeout=10)
    print(f"\nexit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == 78
    m = re.search(rf"^{re.escape(str(config))}:(\d+):(\d+): (.+)$", r.stderr, re.M)
    assert m, f"no file:line:column: message: {r.stderr!r}"
    assert (int(m.group(1)), int(m.group(2))) == (8, 17), "points at the key_file value"
    assert f"endpoint 'lte': 'signing': key file {tmp_path / name}: {phrase}" in m.group(3)
