"""UDP server and client endpoints with pymavlink and plain sockets as the peers."""
from __future__ import annotations

import socket
import time

from pymavlink import mavutil

from helpers import (BIG_RCVBUF, HOST, FrameMaker, corrupt_crc, drain, free_port, raw_v2_frame,
                     recv_datagrams, split_stream, udp_client, udp_server, udp_socket)


def recv_msgs(conn, count: int, timeout: float = 5.0, type_=None):
    """Up to `count` messages from a pymavlink connection (bounded by `timeout`)."""
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < count and time.monotonic() < deadline:
        m = conn.recv_match(type=type_, blocking=True, timeout=0.2)
        if m is not None and m.get_type() != "BAD_DATA":
            out.append(m)
    return out


def test_vehicle_gcs_both_directions_pymavlink(start_daemon):
    """vehicle (pymavlink udpin) <-udp client- mavbond -udp server-> GCS (pymavlink udpout)."""
    gcs_port, veh_port = free_port(), free_port()
    vehicle = mavutil.mavlink_connection(f"udpin:{HOST}:{veh_port}", source_system=1,
                                         source_component=1)
    d = start_daemon([udp_server("gcs", gcs_port), udp_client("ap", veh_port)])
    gcs = mavutil.mavlink_connection(f"udpout:{HOST}:{gcs_port}", source_system=255,
                                     source_component=190)
    # 300 datagrams at once overflow a default receive buffer (256 small datagrams fit)
    for conn in (gcs, vehicle):
        conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, BIG_RCVBUF)
    try:
        # The GCS speaks first (the server learns it as a peer); the vehicle learns the
        # daemon's address from what reaches it.
        gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        hb = recv_msgs(vehicle, 1, type_="HEARTBEAT")
        assert hb and hb[0].get_srcSystem() == 255 and hb[0].get_srcComponent() == 190

        sent = []
        for i in range(300):
            if i % 10 == 0:
                msg = vehicle.mav.heartbeat_encode(2, 3, 81, 0, 4)
            elif i % 3 == 0:
                msg = vehicle.mav.global_position_int_encode(i, 473977420, 85455940, 500000,
                                                             10000, 1, 2, 3, 9000)
            else:
                msg = vehicle.mav.attitude_encode(i * 4, 0.1, -0.2, 1.5, 0.0, 0.01, -0.01)
            vehicle.mav.send(msg)
            sent.append(bytes(msg.get_msgbuf()))
            if i % 50 == 49:
                time.sleep(0.01)  # 300 at once could overflow the daemon's receive buffer
        got = recv_msgs(gcs, len(sent), timeout=5)
        got_bytes = [bytes(m.get_msgbuf()) for m in got]
        print(f"\nvehicle -> GCS: sent {len(sent)} frames, GCS received {len(got_bytes)}; "
              f"stats {d.stats()}")
        assert got_bytes == sent, "telemetry must reach the GCS complete, in order, byte-identical"

        # A command from the GCS to the vehicle.
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
        cmd = recv_msgs(vehicle, 1, type_="COMMAND_LONG")
        assert cmd, "COMMAND_LONG from the GCS never reached the vehicle"
        c = cmd[0]
        assert (c.target_system, c.target_component, c.command, c.param1) == (1, 1, 400, 1.0)
        assert (c.get_srcSystem(), c.get_srcComponent()) == (255, 190)
        print(f"GCS -> vehicle: COMMAND_LONG {c.command} param1={c.param1} delivered")

        # Nothing the GCS sent came back to it.
        echoes = [m for m in recv_msgs(gcs, 10, timeout=0.5) if m.get_srcSystem() == 255]
        assert echoes == []

        st = d.stats()
        print("stats:", st)
        assert st["gcs"]["rx_frames"] == 2 and st["gcs"]["tx_frames"] == len(sent)
        assert st["ap"]["rx_frames"] == len(sent) and st["ap"]["tx_frames"] == 2
        assert st["gcs"]["crc_errors"] == 0 and st["ap"]["crc_errors"] == 0
    finally:
        gcs.close()
        vehicle.close()
    assert d.stop() == 0


def test_several_gcs_peers_broadcast_targeted_no_echo(start_daemon):
    gcs_port, veh_port = free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([udp_server("gcs", gcs_port), udp_client("ap", veh_port)])
    peers = [udp_socket() for _ in range(3)]
    makers = [FrameMaker(255, 190 + i) for i in range(3)]
    vm = FrameMaker(1, 1)
    daemon_gcs = (HOST, gcs_port)
    try:
        # Each GCS introduces itself; peer i's HEARTBEAT reaches the vehicle and the peers
        # that spoke before it, never peer i itself.
        hbs = []
        for p, m in zip(peers, makers):
            hbs.append(m.heartbeat(6))
            p.sendto(hbs[-1], daemon_gcs)
            time.sleep(0.05)
        # (the daemon's "ap" socket address: where its datagrams come from)
        veh.settimeout(3)
        at_vehicle = []
        for _ in range(3):
            data, daemon_ap = veh.recvfrom(65536)
            at_vehicle += split_stream(data)
        veh.settimeout(None)
        assert at_vehicle == hbs
        got = [[f for d_ in recv_datagrams(p, None, timeout=1, quiet=0.2) for f in split_stream(d_)]
               for p in peers]
        print(f"\nheartbeats seen by peers: {[len(g) for g in got]}")
        assert got[0] == [hbs[1], hbs[2]]
        assert got[1] == [hbs[2]]
        assert got[2] == []

        # The vehicle's broadcasts reach every peer, complete and in order.
        telemetry = vm.telemetry(50)
        for f in telemetry:
            veh.sendto(f, daemon_ap)
        for i, p in enumerate(peers):
            frames = [f for d_ in recv_datagrams(p, len(telemetry), timeout=3) for f in split_stream(d_)]
            print(f"peer {i}: {len(frames)}/{len(telemetry)} vehicle broadcasts")
            assert frames == telemetry

        # A frame targeted at GCS (255, 191) reaches peer 1 only.
        ack = vm.pack(vm.mod.MAVLink_mission_ack_message(255, 191, 0))
        veh.sendto(ack, daemon_ap)
        got = [[f for d_ in recv_datagrams(p, None, timeout=1, quiet=0.3) for f in split_stream(d_)]
               for p in peers]
        print(f"MISSION_ACK to (255,191): seen by peers {[len(g) for g in got]}")
        assert got == [[], [ack], []]

        # Target (255, 0): every component of system 255 -> every peer.
        ack0 = vm.pack(vm.mod.MAVLink_mission_ack_message(255, 0, 0))
        veh.sendto(ack0, daemon_ap)
        got = [[f for d_ in recv_datagrams(p, None, timeout=1, quiet=0.3) for f in split_stream(d_)]
               for p in peers]
        assert got == [[ack0], [ack0], [ack0]]

        # A target heard nowhere: sent everywhere but the source.
        ack_unknown = vm.pack(vm.mod.MAVLink_mission_ack_message(42, 42, 0))
        veh.sendto(ack_unknown, daemon_ap)
        got = [[f for d_ in recv_datagrams(p, None, timeout=1, quiet=0.3) for f in split_stream(d_)]
               for p in peers]
        assert got == [[ack_unknown]] * 3

        # A command from peer 0 to the vehicle goes to the vehicle only: not to the other
        # peers (the target is known on "ap"), not back to peer 0.
        drain(veh)
        cmd = makers[0].command_long(1, 1)
        peers[0].sendto(cmd, daemon_gcs)
        at_vehicle = [f for d_ in recv_datagrams(veh, 1, timeout=2) for f in split_stream(d_)]
        assert at_vehicle == [cmd]
        got = [[f for d_ in recv_datagrams(p, None, timeout=1, quiet=0.3) for f in split_stream(d_)]
               for p in peers]
        assert got == [[], [], []], "a targeted command must not reach other GCSs or echo back"
        print("COMMAND_LONG from peer 0: vehicle only")

        st = d.stats()
        print("stats:", st)
        assert st["gcs"]["rx_frames"] == 4
        assert st["gcs"]["tx_frames"] == 3 + 3 * len(telemetry) + 1 + 3 + 3
    finally:
        for p in peers:
            p.close()
        veh.close()
    assert d.stop() == 0


def test_routes_learned_only_from_crc_checked_frames(start_daemon):
    """A frame whose CRC could not be checked (unknown id) or failed teaches no route: a
    reply targeted at its sender goes everywhere, as for any unknown target. A good frame
    does teach one."""
    gcs_port, veh_port = free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([udp_server("gcs", gcs_port), udp_client("ap", veh_port)])
    a, b = udp_socket(), udp_socket()
    vm = FrameMaker(1, 1)
    try:
        a.sendto(FrameMaker(255, 190).heartbeat(6), (HOST, gcs_port))
        _, daemon_ap = veh.recvfrom(65536)
        b.sendto(FrameMaker(254, 190).heartbeat(6), (HOST, gcs_port))
        recv_datagrams(veh, 1, timeout=2)
        # From peer A: an unknown-id frame from (77,1), a bad-CRC HEARTBEAT from (78,1), a
        # good HEARTBEAT from (79,1).
        a.sendto(raw_v2_frame(50000, b"custom", sysid=77, compid=1), (HOST, gcs_port))
        a.sendto(corrupt_crc(FrameMaker(78, 1).heartbeat()), (HOST, gcs_port))
        a.sendto(FrameMaker(79, 1).heartbeat(), (HOST, gcs_port))
        recv_datagrams(veh, 2, timeout=2)
        drain(a), drain(b)
        seen = {}
        for target in (77, 78, 79):
            ack = vm.pack(vm.mod.MAVLink_mission_ack_message(target, 1, 0))
            veh.sendto(ack, daemon_ap)
            seen[target] = [len(recv_datagrams(p, None, timeout=1, quiet=0.3)) for p in (a, b)]
        print(f"\nMISSION_ACK to 77 (unknown id), 78 (bad CRC), 79 (good): peers A/B got {seen}")
        assert seen[77] == [1, 1], "an unknown-id frame must not teach a route"
        assert seen[78] == [1, 1], "a bad-CRC frame must not teach a route"
        assert seen[79] == [1, 0], "a good frame teaches a route"
    finally:
        a.close()
        b.close()
        veh.close()
    assert d.stop() == 0


def test_udp_peer_timeout(start_daemon):
    """A UDP server forgets a peer silent for peer_timeout: it gets nothing more."""
    gcs_port, veh_port = free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([udp_server("gcs", gcs_port, peer_timeout="1s"), udp_client("ap", veh_port)])
    quiet, chatty = udp_socket(), udp_socket()
    vm = FrameMaker(1, 1)
    try:
        quiet.sendto(FrameMaker(255, 190).heartbeat(6), (HOST, gcs_port))
        _, daemon_ap = veh.recvfrom(65536)
        t_end = time.monotonic() + 2.5
        while time.monotonic() < t_end:  # chatty keeps talking, quiet does not
            chatty.sendto(FrameMaker(254, 190).heartbeat(6), (HOST, gcs_port))
            time.sleep(0.2)
        d.wait_log(r"\[udp:gcs\] peer .* forgotten", timeout=2)
        drain(quiet), drain(chatty)
        veh.sendto(vm.heartbeat(), daemon_ap)
        got_quiet = recv_datagrams(quiet, None, timeout=0.7, quiet=0.5)
        got_chatty = recv_datagrams(chatty, None, timeout=0.7, quiet=0.5)
        print(f"\nafter peer_timeout: quiet peer got {len(got_quiet)}, chatty peer got {len(got_chatty)}")
        assert got_quiet == [] and len(got_chatty) == 1
    finally:
        quiet.close()
        chatty.close()
        veh.close()
    assert d.stop() == 0
