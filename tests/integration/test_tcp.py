"""TCP server (pymavlink connects to the daemon) and TCP client (the daemon connects to us,
and reconnects)."""
from __future__ import annotations

import socket
import time

from pymavlink import mavutil

from helpers import (HOST, FrameMaker, free_port, recv_datagrams, split_stream, tcp_client,
                     tcp_server, udp_server, udp_socket)


def read_stream_frames(conn: socket.socket, count: int, timeout: float = 5.0):
    buf = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        frames = split_stream(buf)
        if len(frames) >= count:
            return frames
        conn.settimeout(max(0.01, min(0.2, deadline - time.monotonic())))
        try:
            chunk = conn.recv(65536)
        except socket.timeout:
            continue
        if not chunk:
            break
        buf += chunk
    return split_stream(buf)


def test_tcp_server_with_pymavlink_client(start_daemon):
    tcp_port, gcs_port = free_port(socket.SOCK_STREAM), free_port()
    d = start_daemon([tcp_server("t", tcp_port), udp_server("gcs", gcs_port)])
    gcs = udp_socket()
    gm = FrameMaker(255, 190)
    vehicle = mavutil.mavlink_connection(f"tcp:{HOST}:{tcp_port}", source_system=1,
                                         source_component=1)
    try:
        d.wait_log(r"\[tcp:t\] client .* connected")
        gcs.sendto(gm.heartbeat(6), (HOST, gcs_port))  # the GCS becomes a known peer
        m = vehicle.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
        assert m is not None and m.get_srcSystem() == 255, "GCS heartbeat never reached the TCP client"

        sent = []
        for i in range(500):
            msg = vehicle.mav.attitude_encode(i, 0.1, 0.2, 0.3, 0, 0, 0) if i % 5 else \
                vehicle.mav.heartbeat_encode(2, 3, 0, 0, 4)
            vehicle.mav.send(msg)
            sent.append(bytes(msg.get_msgbuf()))
        got = [f for dg in recv_datagrams(gcs, len(sent), timeout=5) for f in split_stream(dg)]
        print(f"\nTCP client -> UDP GCS: sent {len(sent)}, received {len(got)}")
        assert got == sent

        cmd = gm.command_long(1, 1)
        gcs.sendto(cmd, (HOST, gcs_port))
        m = vehicle.recv_match(type="COMMAND_LONG", blocking=True, timeout=3)
        assert m is not None and bytes(m.get_msgbuf()) == cmd
        st = d.stats()
        print("stats:", st)
        assert st["t"]["rx_frames"] == len(sent) and st["t"]["tx_frames"] == 2
        assert st["gcs"]["tx_frames"] == len(sent)
    finally:
        vehicle.close()
        gcs.close()
    d.wait_log(r"\[tcp:t\] client .* gone")
    assert d.alive()
    assert d.stop() == 0


def test_tcp_client_connects_and_reconnects(start_daemon):
    tc_port, gcs_port = free_port(socket.SOCK_STREAM), free_port()
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind((HOST, tc_port))
    listener.listen(1)
    listener.settimeout(5)
    d = start_daemon([tcp_client("tc", tc_port, reconnect_min="100ms", reconnect_max="1s"),
                      udp_server("gcs", gcs_port)])
    gcs = udp_socket()
    gm = FrameMaker(255, 190)
    vm = FrameMaker(1, 1)
    conns = []
    try:
        for round_ in range(2):
            t0 = time.monotonic()
            conn, _ = listener.accept()
            conns.append(conn)
            d.wait_log(r"\[tcp:tc\] connected to", count=round_ + 1)
            print(f"\nround {round_}: daemon connected after {time.monotonic() - t0:.2f}s")

            # GCS -> daemon -> our TCP server
            hb = gm.heartbeat(6)
            gcs.sendto(hb, (HOST, gcs_port))
            assert read_stream_frames(conn, 1, timeout=3) == [hb]

            # our TCP server -> daemon -> GCS, a few hundred frames in one write
            frames = vm.telemetry(300)
            conn.sendall(b"".join(frames))
            got = [f for dg in recv_datagrams(gcs, len(frames), timeout=5) for f in split_stream(dg)]
            print(f"round {round_}: TCP -> UDP {len(got)}/{len(frames)} frames")
            assert got == frames

            if round_ == 0:
                # Drop the connection and stop listening: the daemon must notice, retry with
                # backoff, and come back when we listen again.
                conn.close()
                listener.close()
                d.wait_log(r"\[tcp:tc\] connection to .* lost")
                time.sleep(0.5)  # a few refused attempts
                assert d.alive()
                listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                listener.bind((HOST, tc_port))
                listener.listen(1)
                listener.settimeout(5)
        st = d.stats()
        print("stats:", st)
        assert st["tc"]["rx_frames"] == 600 and st["tc"]["tx_frames"] == 2
        assert st["gcs"]["tx_frames"] == 600
    finally:
        for c in conns:
            c.close()
        listener.close()
        gcs.close()
    assert d.stop() == 0


def test_tcp_server_several_clients_no_echo(start_daemon):
    """Each accepted client is an endpoint: a broadcast from one client reaches the others,
    never itself; a frame targeted at a system heard on client 2 reaches client 2 only."""
    tcp_port = free_port(socket.SOCK_STREAM)
    d = start_daemon([tcp_server("t", tcp_port)])
    clients = []
    try:
        for i in range(3):
            clients.append(socket.create_connection((HOST, tcp_port), timeout=3))
            d.wait_log(r"\[tcp:t\] client .* connected", count=i + 1)
        makers = [FrameMaker(10 + i, 1) for i in range(3)]
        hbs = [m.heartbeat() for m in makers]
        for c, hb in zip(clients, hbs):
            c.sendall(hb)
            time.sleep(0.1)
        seen = [read_stream_frames(c, 3, timeout=0.7) for c in clients]
        print(f"\nheartbeats seen by TCP clients: {[len(s) for s in seen]}")
        for i, s in enumerate(seen):
            assert s == [hb for j, hb in enumerate(hbs) if j != i]
        cmd = makers[0].command_long(12, 1)
        clients[0].sendall(cmd)
        seen = [read_stream_frames(c, 1, timeout=0.7) for c in clients]
        print(f"COMMAND_LONG to (12,1): seen by {[len(s) for s in seen]}")
        assert seen == [[], [], [cmd]]
        st = d.stats()["t"]
        assert st["rx_frames"] == 4 and st["tx_frames"] == 7
    finally:
        for c in clients:
            c.close()
    assert d.stop() == 0
