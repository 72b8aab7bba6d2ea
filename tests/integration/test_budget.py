"""A link with a transmit budget (`tx_rate`): a 57600-baud radio on a real pseudo-terminal,
offered twice what it carries (an ArduPilot-like stream at 248 frames/s, commands, an FTP
transfer), with the daemon frozen for a second in the middle as a busy companion computer
freezes it. Judged from the bytes on the pty and the daemon's own counters, never the clock:
every command goes out, none behind a frame that came after it; telemetry is thinned to the
newest sample of each message, never reordered, and its last sample goes; bulk arrives whole and
in order; the line never carries more than the rate allows; every frame is accounted for."""
from __future__ import annotations

import re
import signal
import time

from helpers import (HOST, FrameMaker, PtyReader, free_port, split_stream, status_document, uart,
                     udp_server, udp_socket)

RATE = 5760      # 57600 baud, 8N1
BURST = 280      # one largest frame: what the line may hold ahead of a command
FPS = 248        # twice what the radio carries at these sizes
SECONDS = 4.0


def telemetry_maker(fm: FrameMaker):
    """frame(i): one of 8 telemetry messages, i in its time field (so each is unique)."""
    m = fm.mod
    makers = [
        lambda i: m.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03),
        lambda i: m.MAVLink_global_position_int_message(i, 473977420, 85455940, 500000, 10000,
                                                         10, 20, 30, 9000),
        lambda i: m.MAVLink_raw_imu_message(i, 1, 2, 3, 4, 5, 6, 7, 8, 9),
        lambda i: m.MAVLink_gps_raw_int_message(i, 3, 473977420, 85455940, 500000, 100, 100,
                                                1000, 9000, 12),
        lambda i: m.MAVLink_servo_output_raw_message(i, 0, 1500, 1500, 1500, 1500, 1100, 1100,
                                                     1100, 1100),
        lambda i: m.MAVLink_rc_channels_message(i, 16, *([1500] * 18), 255),
        lambda i: m.MAVLink_scaled_pressure_message(i, 1013.2, 0.1, 2500),
        lambda i: m.MAVLink_local_position_ned_message(i, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3),
    ]
    return lambda i: fm.pack(makers[i % len(makers)](i))


def ftp_frame(fm: FrameMaker, k: int) -> bytes:
    payload = bytes([k & 0xFF, k >> 8]) + bytes(249)
    return fm.pack(fm.mod.MAVLink_file_transfer_protocol_message(0, 0, 0, list(payload[:251])))


def wait_line_settled(sock_path, reader: PtyReader, sent, timeout: float = 30.0):
    """Until, by the daemon's own counters, every frame of `sent` ((class, key, frame) each)
    went on the radio's line or was thinned, and the pty gave the reader every byte written:
    a quiet spell on a busy machine is no proof of the end (the daemon may be the one waiting
    for the CPU)."""
    offered = {k: sum(1 for s in sent if s[0] == k) for k in ("control", "telemetry", "bulk")}

    def settled():
        radio = next(e for e in status_document(sock_path)["endpoints"] if e["name"] == "radio")
        b = radio["tx_budget"]
        handled = all(b[k]["frames"] + b[k].get("thinned", 0) + b[k].get("dropped", 0) == v
                      for k, v in offered.items())
        written = radio["tx_frames"] == sum(b[k]["frames"] for k in offered)
        return handled and written and len(reader.data) == radio["tx_bytes"]

    deadline = time.monotonic() + timeout
    while not settled():
        assert time.monotonic() < deadline, "the budget's frames did not all reach the line"
        time.sleep(0.1)


def test_a_saturated_radio_sends_commands_first_and_thins_telemetry(start_daemon, pty_pair,
                                                                     tmp_path):
    pty = pty_pair()
    ap_port = free_port()
    sock_path = tmp_path / "status.sock"
    d = start_daemon([uart("radio", pty.path, baud=57600, tx_rate="baud"),
                      udp_server("ap", ap_port)], status_socket=str(sock_path))
    d.wait_log(r"\[uart:radio\] .* open at 57600 baud")
    reader = PtyReader(pty)
    reader.start()
    fm = FrameMaker(1, 1)
    tele = telemetry_maker(fm)

    # The input, in the order the test sends it: (kind, key, frame).
    sent = []
    n = int(FPS * SECONDS)
    for i in range(n):
        sent.append(("telemetry", i, tele(i)))
        if i % 25 == 12:   # a command about every 100 ms, each its own
            sent.append(("control", i, fm.command_long(0, 0, 400 + i // 25)))
        if i % 62 == 30:   # a heartbeat about every 250 ms
            sent.append(("control", i, fm.pack(fm.mod.MAVLink_heartbeat_message(2, 3, 0, i, 4, 3))))
        if i % 25 == 3:    # FTP at 10 frames/s: bulk
            sent.append(("bulk", i // 25, ftp_frame(fm, i // 25)))
    index = {f: k for k, (_, _, f) in enumerate(sent)}
    assert len(index) == len(sent), "every frame sent is unique"

    src = udp_socket()
    t_start = time.monotonic()
    stopped_at = None   # halfway the daemon is frozen for 1 s: the stream piles up meanwhile
    try:
        for _, i, frame in sent:
            due = t_start + i / FPS
            while time.monotonic() < due:
                time.sleep(0.002)
            if stopped_at is None and i >= n // 2:
                d.proc.send_signal(signal.SIGSTOP)
                stopped_at = time.monotonic()
            elif stopped_at and time.monotonic() - stopped_at > 1.0:
                d.proc.send_signal(signal.SIGCONT)
                stopped_at = 0
            src.sendto(frame, (HOST, ap_port))
        d.proc.send_signal(signal.SIGCONT)
        # What the budget still holds goes out after the stream.
        wait_line_settled(sock_path, reader, sent)
        t_end = reader.last_byte
    finally:
        reader.stop_flag.set()
        reader.join(2)
        src.close()

    out = split_stream(bytes(reader.data))
    assert b"".join(out) == bytes(reader.data), "only whole frames on the line"
    pos = [index[f] for f in out]
    kinds = [sent[p][0] for p in pos]
    assert len(set(pos)) == len(pos), "no frame twice"

    # Every command and heartbeat went, in order, and none after a frame sent after it.
    control_in = [k for k, s in enumerate(sent) if s[0] == "control"]
    control_out = [p for p in pos if sent[p][0] == "control"]
    assert control_out == control_in
    overtaken = 0
    for at, p in enumerate(pos):
        if sent[p][0] != "control":
            continue
        ahead = pos[:at]
        assert max(ahead, default=-1) < p, f"a frame sent after command {p} went before it"
        overtaken += sum(1 for q in pos[at + 1:] if q < p)
    assert overtaken > 0, "the freeze's backlog: commands went ahead of older telemetry"

    # Telemetry: per message newest first-only, each message's last sample went.
    tele_out = [p for p in pos if sent[p][0] == "telemetry"]
    by_msg = {}
    for p in tele_out:
        by_msg.setdefault(sent[p][1] % 8, []).append(sent[p][1])
    assert len(by_msg) == 8, "every message kept a share"
    for m, seq in by_msg.items():
        assert seq == sorted(seq), f"message {m} went out of order"
        assert seq[-1] == max(i for i in range(n) if i % 8 == m), f"message {m}'s last sample"

    # Bulk: whole and in order.
    bulk_out = [sent[p][1] for p in pos if sent[p][0] == "bulk"]
    assert bulk_out == [s[1] for s in sent if s[0] == "bulk"]

    # The line: what is not control never beyond the rate and one frame over the window.
    window = t_end - t_start
    paced = sum(len(f) for f, k in zip(out, kinds) if k != "control")
    assert paced <= RATE * window + BURST, (paced, RATE * window)

    # The daemon's own accounting: each class's frames as the pty got them, and every
    # telemetry frame sent either went, or was thinned.
    doc = status_document(sock_path)
    radio = next(e for e in doc["endpoints"] if e["name"] == "radio")
    b = radio["tx_budget"]
    assert b["rate"] == RATE
    assert b["control"]["frames"] == len(control_in) and b["control"]["waited"] == 0
    assert b["telemetry"]["frames"] == len(tele_out)
    assert b["telemetry"]["frames"] + b["telemetry"]["thinned"] + b["telemetry"]["dropped"] == n
    assert b["telemetry"]["dropped"] == 0 and b["telemetry"]["thinned"] > 0
    assert b["bulk"]["frames"] == len(bulk_out) and b["bulk"]["dropped"] == 0
    assert radio["tx_frames"] == len(out) and radio["tx_dropped"] == 0
    offered = sum(len(s[2]) for s in sent) / SECONDS
    print(f"\n{len(sent)} frames offered in {SECONDS:.0f} s ({offered:.0f} B/s) "
          f"to a {RATE} B/s radio, frozen 1 s; on the line in {window:.1f} s: "
          f"{sum(map(len, out)) / window:.0f} B/s; control {b['control']['frames']} "
          f"(every one, none waited, {overtaken} older frames overtaken), telemetry "
          f"{b['telemetry']['frames']} of {n} ({b['telemetry']['thinned']} thinned, "
          f"{b['telemetry']['waited']} waited), bulk {b['bulk']['frames']} of "
          f"{len(bulk_out)} in order")
    assert d.stop() == 0


def test_a_budget_changes_on_reload_with_no_restart(start_daemon, pty_pair, tmp_path):
    """A radio's budget raised from 2 kB/s (under the stream) to 20 kB/s (over it) by a reload
    mid-stream: the UART is not reopened, nothing is lost but what the old budget thinned,
    and once the new budget holds every frame goes through."""
    pty = pty_pair()
    ap_port = free_port()
    sock_path = tmp_path / "status.sock"
    radio = uart("radio", pty.path, baud=57600, tx_rate="2kB/s")
    d = start_daemon([radio, udp_server("ap", ap_port)], status_socket=str(sock_path))
    d.wait_log(r"\[uart:radio\] .* open at 57600 baud")
    reader = PtyReader(pty)
    reader.start()
    fm = FrameMaker(1, 1)
    tele = telemetry_maker(fm)
    sent, n, fps = [], 600, 100   # 6 s at about 4 kB/s; the reload at 2 s
    for i in range(n):
        sent.append(("telemetry", i, tele(i)))
        if i % 10 == 5:
            sent.append(("control", i, fm.command_long(0, 0, 400 + i // 10)))
    index = {f: k for k, (_, _, f) in enumerate(sent)}
    src = udp_socket()
    t_start, reloaded = time.monotonic(), False
    try:
        for _, i, frame in sent:
            while time.monotonic() < t_start + i / fps:
                time.sleep(0.002)
            if not reloaded and i >= 2 * fps:
                d.config_path.write_text(d.config_path.read_text().replace(
                    "tx_rate: 2kB/s", "tx_rate: 20kB/s"))
                d.proc.send_signal(signal.SIGHUP)
                reloaded = True
            src.sendto(frame, (HOST, ap_port))
        d.wait_log(r"reload: \[radio\] transmit budget now 20000 B/s")
        wait_line_settled(sock_path, reader, sent)
    finally:
        reader.stop_flag.set()
        reader.join(2)
        src.close()

    log = d.log()
    assert len(re.findall(r"\[uart:radio\] .* open at", log)) == 1, "the UART was not reopened"
    assert re.search(r"reloaded: 2 endpoints kept, 0 stopped, 0 started", log)
    out = split_stream(bytes(reader.data))
    pos = [index[f] for f in out]
    assert len(set(pos)) == len(pos)
    control = [p for p in pos if sent[p][0] == "control"]
    assert control == [k for k, s in enumerate(sent) if s[0] == "control"]
    for m in range(8):
        seq = [sent[p][1] for p in pos if sent[p][0] == "telemetry" and sent[p][1] % 8 == m]
        assert seq == sorted(seq)
    # The last second went whole: the new budget carries the stream.
    tail = [k for k, s in enumerate(sent) if s[0] == "telemetry" and s[1] >= n - fps]
    assert set(tail) <= set(pos)
    doc = status_document(sock_path)
    r = next(e for e in doc["endpoints"] if e["name"] == "radio")
    t = r["tx_budget"]["telemetry"]
    assert r["tx_budget"]["rate"] == 20000
    assert t["frames"] == len(pos) - len(control), "the counters went on across the reload"
    assert t["frames"] + t["thinned"] == n and t["dropped"] == 0 and t["thinned"] > 0
    assert r["tx_dropped"] == 0
    print(f"\nreload 2 kB/s -> 20 kB/s mid-stream: every one of {len(control)} commands, "
          f"telemetry {t['frames']} of {n} ({t['thinned']} thinned), the UART opened once")
    assert d.stop() == 0


def test_what_a_bond_member_thins_takes_no_number(start_daemon, pty_pair, tmp_path):
    """The radio as a bond's member (routing/egress_numbering.h), offered twice what it
    carries: the frames it thins never take a sequence number, so the far side's stream of
    each source is gapless but for the source's own gap (3 numbers the autopilot skipped,
    as frames lost on its UART would be), and every frame goes in the source's order. The
    same stream to a link in no bond keeps the autopilot's numbers: thinned ones are gaps."""
    bonded, plain = pty_pair(), pty_pair()
    ap_port = free_port()
    sock_path = tmp_path / "status.sock"
    d = start_daemon([uart("radio", bonded.path, baud=57600, tx_rate="baud", bond="vehicle"),
                      uart("plain", plain.path, baud=57600, tx_rate="baud"),
                      udp_server("ap", ap_port)],
                     bonds=[{"name": "vehicle"}], status_socket=str(sock_path))
    readers = [PtyReader(bonded), PtyReader(plain)]
    for r in readers:
        r.start()
    fm = FrameMaker(1, 1)
    tele = telemetry_maker(fm)

    def of_vehicle(reader):
        return [f for f in split_stream(bytes(reader.data))
                if (f[5], f[6]) == (1, 1) and f[7] | f[8] << 8 | f[9] << 16 != 252]

    n, skip_at = int(FPS * 3), int(FPS * 1.5)
    src = udp_socket()
    t_start = time.monotonic()
    try:
        for i in range(n):
            while time.monotonic() < t_start + i / FPS:
                time.sleep(0.002)
            # pymavlink's pack() leaves the counter alone: the source numbers its frames here,
            # skipping 3 once (its own gap).
            fm.mav.seq = (i + (3 if i >= skip_at else 0)) % 256
            src.sendto(tele(i), (HOST, ap_port))
        # The end by the daemon's counters, not a quiet spell: each budget settled every frame
        # offered, the plain line's reader has every byte written, and the bond member's every
        # frame it numbered (its count markers and reports are not the source's).
        deadline = time.monotonic() + 30
        while True:
            doc = status_document(sock_path)
            ends = {e["name"]: e for e in doc["endpoints"]}
            settled = all(sum(ends[k]["tx_budget"]["telemetry"][c] for c in
                              ("frames", "thinned", "dropped")) == n for k in ("radio", "plain"))
            plain_e = ends["plain"]
            numbered = next(b for b in doc["bonds"] if b["name"] == "vehicle")["numbering"]
            if (settled and plain_e["tx_frames"] == plain_e["tx_budget"]["telemetry"]["frames"]
                    and len(readers[1].data) == plain_e["tx_bytes"]
                    and len(of_vehicle(readers[0])) == numbered["numbered"]):
                break
            assert time.monotonic() < deadline, "the budgets' frames did not all reach the lines"
            time.sleep(0.1)
    finally:
        for r in readers:
            r.stop_flag.set()
            r.join(2)
        src.close()

    def steps(frames):
        seqs = [f[4] for f in frames]
        return [(b - a) % 256 for a, b in zip(seqs, seqs[1:])]

    on_bond, on_plain = of_vehicle(readers[0]), of_vehicle(readers[1])
    doc = status_document(sock_path)
    thinned = {e["name"]: e["tx_budget"]["telemetry"]["thinned"] for e in doc["endpoints"]
               if e["name"] in ("radio", "plain")}
    assert thinned["radio"] > n // 4 and thinned["plain"] > n // 4, thinned
    bond_steps = steps(on_bond)
    assert sorted(set(bond_steps)) == [1, 4] and bond_steps.count(4) == 1, \
        f"gapless but for the source's 3: {sorted(set(bond_steps))}"
    # In the source's order: each frame's time field, newest first-only per message.
    times = [int.from_bytes(f[10:14], "little") for f in on_bond]
    for m in range(8):
        mine = [t for t in times if t % 8 == m]
        assert mine == sorted(mine)
    plain_steps = steps(on_plain)
    assert sum(s - 1 for s in plain_steps) >= thinned["plain"], \
        "a link in no bond keeps the source's numbers: each thinned frame a gap"
    numbered = next(b for b in doc["bonds"] if b["name"] == "vehicle")["numbering"]
    assert numbered["numbered"] == len(on_bond), "one number for each frame it sent (its count "\
        "markers are the link's own)"
    print(f"\n{n} frames offered at twice the radio's rate: the bond member sent {len(on_bond)} "
          f"({thinned['radio']} thinned), numbered gapless but for the source's own gap of 3; "
          f"the link in no bond sent {len(on_plain)} ({thinned['plain']} thinned) with "
          f"{sum(s - 1 for s in plain_steps)} numbers skipped")
    assert d.stop() == 0
