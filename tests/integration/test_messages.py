"""unknown_messages: forward|drop, and the per-endpoint allow/block message filters."""
from __future__ import annotations

import pytest

from helpers import (HOST, FrameMaker, free_port, raw_v2_frame, recv_datagrams, send_lockstep,
                     split_stream, tlog, udp_client, udp_server, udp_socket)


def unknown_frames():
    """Frames with ids that the `all` dialect does not define (8 and 411 are what PX4 sent in
    the shared raw capture; 50000 is any custom id)."""
    out = []
    for i, mid in enumerate([8, 411, 50000, 8, 411]):
        f = raw_v2_frame(mid, bytes(range(i, i + 12)), seq=i)
        assert tlog.crc_ok(f) is None
        out.append(f)
    return out


def exchange(d, in_port, rx, frames, expect):
    tx = udp_socket()
    try:
        for f in frames:
            tx.sendto(f, (HOST, in_port))
        got = [f for dg in recv_datagrams(rx, expect, timeout=3) for f in split_stream(dg)]
        # nothing more than expected arrives
        got += [f for dg in recv_datagrams(rx, None, timeout=0.3, quiet=0.3) for f in split_stream(dg)]
    finally:
        tx.close()
    return got, d.stats()["in"]


@pytest.mark.parametrize("policy", ["forward", "drop", None], ids=["forward", "drop", "default"])
def test_unknown_messages_policy(start_daemon, policy):
    vm = FrameMaker(1, 1)
    unknown = unknown_frames()
    known = [vm.heartbeat(), vm.attitude(1), vm.sys_status()]
    frames = [known[0], unknown[0], unknown[1], known[1], unknown[2], unknown[3], unknown[4],
              known[2]]
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    top = {} if policy is None else {"unknown_messages": policy}
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)], **top)
    try:
        want = known if policy == "drop" else frames
        got, st = exchange(d, in_port, rx, frames, len(want))
    finally:
        rx.close()
    print(f"\nunknown_messages={policy or 'default'}: sent {len(frames)} ({len(unknown)} unknown), "
          f"forwarded {len(got)}; in: rx_frames={st['rx_frames']} unknown_ids={st['unknown_ids']} "
          f"crc_errors={st['crc_errors']}")
    assert got == want
    assert st["unknown_ids"] == len(unknown), "unknown ids are counted, forwarded or not"
    assert st["crc_errors"] == 0
    assert st["rx_frames"] == len(want)
    assert d.stop() == 0


def test_block_out_attitude(start_daemon):
    """block_out: [ATTITUDE] on the GCS endpoint: no ATTITUDE reaches the GCS, the rest
    does, and another endpoint without the filter still gets ATTITUDE."""
    gcs_port, veh_port, log_port = free_port(), free_port(), free_port()
    veh, logger = udp_socket(veh_port), udp_socket(log_port)
    d = start_daemon([udp_server("gcs", gcs_port, block_out=["ATTITUDE"]),
                      udp_client("ap", veh_port), udp_client("logger", log_port)])
    gcs = udp_socket()
    gm, vm = FrameMaker(255, 190), FrameMaker(1, 1)
    try:
        gcs.sendto(gm.heartbeat(6), (HOST, gcs_port))
        data, daemon_ap = veh.recvfrom(65536)
        recv_datagrams(logger, 1, timeout=2)
        telemetry = vm.telemetry(300)
        at_logger = send_lockstep(veh, daemon_ap, telemetry, logger)
        attitude_id = vm.mod.MAVLINK_MSG_ID_ATTITUDE
        want = [f for f in telemetry if tlog.msgid(f) != attitude_id]
        n_att = len(telemetry) - len(want)
        got = [f for dg in recv_datagrams(gcs, len(want), timeout=3) for f in split_stream(dg)]
        got += [f for dg in recv_datagrams(gcs, None, timeout=0.3) for f in split_stream(dg)]
        st = d.stats()
    finally:
        gcs.close()
        veh.close()
        logger.close()
    print(f"\nblock_out [ATTITUDE]: vehicle sent {len(telemetry)} ({n_att} ATTITUDE); GCS got "
          f"{len(got)}, logger got {len(at_logger)}; gcs tx_filtered={st['gcs']['tx_filtered']}")
    assert n_att > 100
    assert got == want
    assert not any(tlog.msgid(f) == attitude_id for f in got)
    assert at_logger == telemetry
    assert st["gcs"]["tx_filtered"] == n_att
    assert st["gcs"]["tx_frames"] == len(want)
    assert d.stop() == 0


def test_allow_in_and_numeric_block(start_daemon):
    """allow_in: [HEARTBEAT, COMMAND_LONG] on the GCS endpoint: a PARAM_REQUEST_READ and a
    MISSION_ACK from the GCS are dropped at the door, the others go on. block_in by numeric
    id (76 = COMMAND_LONG) on a second GCS endpoint drops its commands."""
    g1_port, g2_port, veh_port = free_port(), free_port(), free_port()
    veh = udp_socket(veh_port)
    d = start_daemon([udp_server("gcs", g1_port, allow_in=["HEARTBEAT", "COMMAND_LONG"]),
                      udp_server("gcs2", g2_port, block_in=[76]),
                      udp_client("ap", veh_port)])
    g1, g2 = udp_socket(), udp_socket()
    m1, m2 = FrameMaker(255, 190), FrameMaker(254, 190)
    try:
        sent1 = [m1.heartbeat(6), m1.param_request_read(1, 1), m1.command_long(1, 1),
                 m1.pack(m1.mod.MAVLink_mission_ack_message(1, 1, 0)), m1.command_long(1, 1, 401)]
        for f in sent1:
            g1.sendto(f, (HOST, g1_port))
        want1 = [sent1[0], sent1[2], sent1[4]]
        got1 = [f for dg in recv_datagrams(veh, len(want1), timeout=3) for f in split_stream(dg)]
        got1 += [f for dg in recv_datagrams(veh, None, timeout=0.3) for f in split_stream(dg)]

        sent2 = [m2.heartbeat(6), m2.command_long(1, 1), m2.param_request_read(1, 1)]
        for f in sent2:
            g2.sendto(f, (HOST, g2_port))
        want2 = [sent2[0], sent2[2]]
        got2 = [f for dg in recv_datagrams(veh, len(want2), timeout=3) for f in split_stream(dg)]
        got2 += [f for dg in recv_datagrams(veh, None, timeout=0.3) for f in split_stream(dg)]
        st = d.stats()
    finally:
        g1.close()
        g2.close()
        veh.close()
    print(f"\nallow_in [HEARTBEAT, COMMAND_LONG]: GCS sent {len(sent1)}, vehicle got {len(got1)}, "
          f"rx_filtered={st['gcs']['rx_filtered']}; block_in [76]: sent {len(sent2)}, got "
          f"{len(got2)}, rx_filtered={st['gcs2']['rx_filtered']}")
    assert got1 == want1
    assert got2 == want2
    assert st["gcs"]["rx_filtered"] == 2
    assert st["gcs2"]["rx_filtered"] == 1
    assert d.stop() == 0


def test_unknown_drop_px4_capture(start_daemon, tlog_dir):
    """The PX4 raw capture with unknown_messages: drop: its 14 frames with ids 8 and 411 are
    not forwarded and are counted; every other frame is."""
    path = tlog_dir / "px4-plane-raw-v2-3412-packets.mavlink"
    if not path.exists():
        pytest.skip(f"{path} missing")
    frames = [f for _, f in tlog.iter_frames(path)]
    want = [f for f in frames if tlog.crc_ok(f) is True]
    n_unknown = sum(1 for f in frames if tlog.crc_ok(f) is None)
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)],
                     unknown_messages="drop")
    tx = udp_socket()
    got = []
    try:
        for i in range(0, len(frames), 100):
            for f in frames[i:i + 100]:
                tx.sendto(f, (HOST, in_port))
            expect = sum(1 for f in frames[:i + 100] if tlog.crc_ok(f) is True)
            got += [f for dg in recv_datagrams(rx, expect - len(got), timeout=2)
                    for f in split_stream(dg)]
        st = d.settle_stats(lambda s: s["in"]["rx_frames"])["in"]
    finally:
        tx.close()
        rx.close()
    print(f"\n{path.name} with unknown_messages=drop: sent {len(frames)}, forwarded {len(got)}, "
          f"unknown_ids={st['unknown_ids']} (expected {n_unknown})")
    assert n_unknown == 14
    assert got == want
    assert st["unknown_ids"] == n_unknown and st["rx_frames"] == len(want)
    assert d.stop() == 0
