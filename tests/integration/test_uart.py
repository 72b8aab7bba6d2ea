"""UART endpoints on real pseudo-terminals: both directions, standard and non-standard baud
rates, a device that goes away mid-stream and comes back, and a device that appears after the
daemon started."""
from __future__ import annotations

import os
import re
import time

import pytest

from helpers import (HOST, FrameMaker, free_port, recv_datagrams, split_stream, uart,
                     udp_client, udp_server, udp_socket)


def uart_warnings(log: str, name: str) -> list:
    return [l for l in log.splitlines() if f"[uart:{name}]" in l and "warning" in l]


@pytest.mark.parametrize("baud", [921600, 1500000])
def test_uart_pty_both_directions(start_daemon, pty_pair, baud):
    pty = pty_pair()
    gcs_port = free_port()
    d = start_daemon([uart("u", pty.path, baud=baud, flow_control=False),
                      udp_server("gcs", gcs_port)])
    d.wait_log(rf"\[uart:u\] {re.escape(pty.path)} open at {baud} baud")
    gcs = udp_socket()
    gm, vm = FrameMaker(255, 190), FrameMaker(1, 1)
    try:
        # UDP -> pty
        hb = gm.heartbeat(6)
        gcs.sendto(hb, (HOST, gcs_port))
        cmds = [gm.command_long(1, 1, 400 + i) for i in range(20)]
        for c in cmds:
            gcs.sendto(c, (HOST, gcs_port))
        want = [hb] + cmds
        out = pty.read_for(timeout=3, until=lambda b: len(split_stream(b)) >= len(want))
        print(f"\n{baud} baud: UDP -> pty {len(split_stream(out))}/{len(want)} frames")
        assert split_stream(out) == want

        # pty -> UDP: 2000 frames written in large chunks
        frames = vm.telemetry(2000)
        pty.write_all(b"".join(frames))
        got = [f for dg in recv_datagrams(gcs, len(frames), timeout=10) for f in split_stream(dg)]
        print(f"{baud} baud: pty -> UDP {len(got)}/{len(frames)} frames")
        assert got == frames
        st = d.stats()
        print("stats:", st)
        assert st["u"]["rx_frames"] == len(frames) and st["u"]["tx_frames"] == len(want)
        assert st["u"]["garbage_bytes"] == 0 and st["u"]["crc_errors"] == 0
    finally:
        gcs.close()
    assert d.stop() == 0


def test_uart_pty_lost_and_back(start_daemon, pty_pair, tmp_path):
    """A UART (a pty behind a symlink, as udev's /dev/serial/by-id) disappears mid-frame and
    comes back: the loss and the return are logged once each (not once per retry), UDP keeps
    flowing both ways during the outage, what was routed to the UART meanwhile is counted as
    dropped, the half frame as garbage, and frames flow both ways through the new device."""
    link = tmp_path / "ttyLINK"
    pty = pty_pair()
    os.symlink(pty.path, link)
    gcs_port, veh_port = free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([uart("u", str(link), baud=921600, reconnect_min="100ms",
                           reconnect_max="400ms"),
                      udp_server("gcs", gcs_port), udp_client("ap", veh_port)])
    d.wait_log(r"\[uart:u\] .*ttyLINK open at 921600 baud")
    gcs = udp_socket()
    gm, um, vm = FrameMaker(255, 190), FrameMaker(1, 1), FrameMaker(2, 1)

    def both_get(frames):
        for sock in (gcs, veh):
            got = [f for dg in recv_datagrams(sock, len(frames), timeout=5)
                   for f in split_stream(dg)]
            assert got == frames

    try:
        hello = gm.heartbeat(6)  # the GCS becomes a known peer; the vehicle learns our address
        gcs.sendto(hello, (HOST, gcs_port))
        data, daemon_ap = veh.recvfrom(65536)
        assert split_stream(data) == [hello]
        out = pty.read_for(timeout=3, until=lambda b: len(b) >= len(hello))
        assert split_stream(out) == [hello]
        before = um.telemetry(200)
        half = um.sys_status()[:15]
        pty.write_all(b"".join(before) + half)  # the device goes away in the middle of a frame
        both_get(before)
        os.unlink(link)
        pty.close()
        d.wait_log(r"\[uart:u\] .*ttyLINK lost")
        t_lost = time.monotonic()

        # The outage: UDP <-> UDP goes on, exactly.
        from_gcs, from_veh = gm.telemetry(100), vm.telemetry(100)
        for f in from_gcs:
            gcs.sendto(f, (HOST, gcs_port))
        got = [f for dg in recv_datagrams(veh, len(from_gcs), timeout=5) for f in split_stream(dg)]
        assert got == from_gcs
        for f in from_veh:
            veh.sendto(f, daemon_ap)
        got = [f for dg in recv_datagrams(gcs, len(from_veh), timeout=5) for f in split_stream(dg)]
        assert got == from_veh
        while time.monotonic() - t_lost < 1.5:  # several retries at 100..400 ms
            time.sleep(0.1)
        assert d.alive()
        outage = d.stats()
        print(f"\nduring the outage: gcs->ap {len(from_gcs)}, ap->gcs {len(from_veh)} delivered; "
              f"u tx_dropped={outage['u']['tx_dropped']}")
        assert outage["u"]["tx_dropped"] == len(from_gcs) + len(from_veh)
        assert outage["gcs"]["tx_frames"] == len(before) + len(from_veh)
        assert outage["ap"]["tx_frames"] == 1 + len(before) + len(from_gcs)

        # The device comes back (another pty behind the same name).
        pty2 = pty_pair()
        t0 = time.monotonic()
        os.symlink(pty2.path, link)
        d.wait_log(r"\[uart:u\] .*ttyLINK open at 921600 baud", count=2, timeout=5)
        print(f"reopened {time.monotonic() - t0:.2f}s after the device came back")
        after = um.telemetry(200)
        pty2.write_all(b"".join(after))
        both_get(after)
        hb = gm.heartbeat(6)
        gcs.sendto(hb, (HOST, gcs_port))
        assert split_stream(pty2.read_for(timeout=3, until=lambda b: len(b) >= len(hb))) == [hb]

        st = d.stats()
        print("stats:", st)
        u = st["u"]
        assert u["rx_frames"] == len(before) + len(after)
        assert u["garbage_bytes"] == len(half), "the half frame is counted, not delivered"
        assert u["tx_frames"] == 2 and u["tx_dropped"] == len(from_gcs) + len(from_veh)
        lines = [l for l in d.log().splitlines() if "[uart:u]" in l]
        print("\n".join(lines))
        assert len(lines) == 3, "open, lost, open again: one line per change, none per retry"
        assert "open at" in lines[0] and "lost" in lines[1] and "open at" in lines[2]
    finally:
        gcs.close()
        veh.close()
    assert d.stop() == 0


def test_uart_missing_device_appears_later(start_daemon, pty_pair, tmp_path):
    fake = tmp_path / "ttyFAKE"
    gcs_port, veh_port = free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([uart("u", str(fake), baud=1500000, reconnect_min="100ms",
                           reconnect_max="500ms"),
                      udp_server("gcs", gcs_port), udp_client("ap", veh_port)])
    gcs = udp_socket()
    gm, vm = FrameMaker(255, 190), FrameMaker(1, 1)
    try:
        d.wait_log(r"\[uart:u\] .*ttyFAKE.*retrying")
        # Other endpoints route while the device is missing.
        hb = gm.heartbeat(6)
        gcs.sendto(hb, (HOST, gcs_port))
        data, daemon_ap = veh.recvfrom(65536)
        assert split_stream(data) == [hb]
        frames = vm.telemetry(50)
        for f in frames:
            veh.sendto(f, daemon_ap)
        got = [f for dg in recv_datagrams(gcs, len(frames), timeout=3) for f in split_stream(dg)]
        assert got == frames
        time.sleep(1.2)
        warnings = uart_warnings(d.log(), "u")
        print(f"\nwarnings while missing: {warnings}")
        assert len(warnings) == 1, "a missing device is logged once"

        # The device appears.
        pty = pty_pair()
        t0 = time.monotonic()
        os.symlink(pty.path, fake)
        d.wait_log(r"\[uart:u\] .*ttyFAKE open at 1500000 baud", timeout=3)
        print(f"opened {time.monotonic() - t0:.2f}s after the device appeared")

        uframes = vm.telemetry(200)
        pty.write_all(b"".join(uframes))
        got = [f for dg in recv_datagrams(gcs, len(uframes), timeout=5) for f in split_stream(dg)]
        print(f"pty -> UDP: {len(got)}/{len(uframes)}")
        assert got == uframes
        cmd = gm.command_long(1, 1)
        gcs.sendto(cmd, (HOST, gcs_port))
        out = pty.read_for(timeout=3, until=lambda b: len(split_stream(b)) >= 1)
        assert split_stream(out) == [cmd]
        st = d.stats()
        print("stats:", st)
        assert st["u"]["rx_frames"] == len(uframes) and st["u"]["tx_frames"] == 1
        assert st["u"]["tx_dropped"] == 1 + len(frames)  # routed to it while it was missing
    finally:
        gcs.close()
        veh.close()
    assert d.stop() == 0
