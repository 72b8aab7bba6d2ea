#!/usr/bin/env python3
"""Sends MAVLink frames through a running mavbond over UDP and checks they arrive, using only
the standard library (the package tests run without the project's .venv).

  route_check.py pair GCS_PORT AUTOPILOT_PORT
      Two UDP server endpoints on 127.0.0.1: a heartbeat from the "autopilot" reaches the
      "gcs" and one from the gcs reaches the autopilot, byte-identical.
  route_check.py stream GCS_PORT AUTOPILOT_PORT SECONDS
      The autopilot sends 50 heartbeats a second for SECONDS (while, say, the daemon reloads);
      the gcs gets every one, once, in order.
  route_check.py bond GCS_PORT RADIO1_PORT RADIO2_PORT
      Frames sent over both links of a bond reach the gcs once (whichever filter drops the
      other copy: linkswitch passes the active link only, dedup drops duplicates), and a
      frame from the gcs reaches the vehicle over the bond.
Exit 0 when every check passes; one line per check on stdout.
"""
import socket
import struct
import sys
import time

HOST = "127.0.0.1"


def x25(data, crc=0xFFFF):
    for b in data:
        tmp = (b ^ crc) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def heartbeat(seq, sysid, compid, mav_type):
    """A MAVLink 2 HEARTBEAT (msgid 0, CRC_EXTRA 50)."""
    payload = struct.pack("<IBBBBB", 0, mav_type, 3, 0x81, 4, 3)
    header = struct.pack("<BBBBBBB", len(payload), 0, 0, seq, sysid, compid, 0) + b"\x00\x00"
    crc = x25(bytes([50]), x25(header + payload))
    return b"\xfd" + header + payload + struct.pack("<H", crc)


def sock():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((HOST, 0))
    s.settimeout(0.2)
    return s


def receive(s, timeout=3.0):
    """Every datagram that arrives within timeout (stops 0.5 s after the first)."""
    got, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            got.append(s.recv(4096))
            deadline = min(deadline, time.monotonic() + 0.5)
        except socket.timeout:
            pass
    return got


FAILED = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what)
    if not ok:
        FAILED.append(what)


def pair(gcs_port, ap_port):
    gcs, ap = sock(), sock()
    hello = heartbeat(0, 255, 190, 6)  # the GCS speaks first: the daemon learns it as a peer
    gcs.sendto(hello, (HOST, gcs_port))
    time.sleep(0.3)
    frame = heartbeat(1, 1, 1, 2)      # an autopilot (MAV_TYPE_QUADROTOR)
    ap.sendto(frame, (HOST, ap_port))
    got = receive(gcs)
    check(got == [frame], f"autopilot -> gcs: heartbeat routed byte-identical ({len(got)} received)")
    back = heartbeat(1, 255, 190, 6)
    gcs.sendto(back, (HOST, gcs_port))
    got = receive(ap)
    check(back in got, f"gcs -> autopilot: heartbeat routed ({len(got)} received)")


def stream(gcs_port, ap_port, seconds):
    gcs, ap = sock(), sock()
    gcs.sendto(heartbeat(0, 255, 190, 6), (HOST, gcs_port))
    time.sleep(0.3)
    sent, got = [], []
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        frame = heartbeat(len(sent) % 256, 1, 1, 2)
        ap.sendto(frame, (HOST, ap_port))
        sent.append(frame)
        next_send = start + len(sent) / 50
        while True:  # receive until the next frame is due
            gcs.settimeout(max(0.001, next_send - time.monotonic()))
            try:
                got.append(gcs.recv(4096))
            except socket.timeout:
                break
    gcs.settimeout(0.2)
    got += receive(gcs, 2.0)
    check(got == sent, f"autopilot -> gcs for {seconds} s: {len(sent)} sent, {len(got)} received, "
          f"{'all once and in order' if got == sent else 'NOT all once in order'}")


def bond(gcs_port, r1_port, r2_port):
    gcs, r1, r2 = sock(), sock(), sock()
    gcs.sendto(heartbeat(0, 255, 190, 6), (HOST, gcs_port))
    time.sleep(0.3)
    frame = heartbeat(7, 1, 1, 2)
    r1.sendto(frame, (HOST, r1_port))
    r2.sendto(frame, (HOST, r2_port))  # the same frame over the second radio
    got = receive(gcs)
    check(got == [frame], f"bond -> gcs: a frame sent over both links delivered once ({len(got)} received)")
    frame2 = heartbeat(8, 1, 1, 2)
    r2.sendto(frame2, (HOST, r2_port))
    r1.sendto(frame2, (HOST, r1_port))
    got = receive(gcs)
    check(got == [frame2], f"bond -> gcs: the next frame, over both links again, delivered once ({len(got)} received)")
    back = heartbeat(1, 255, 190, 6)
    gcs.sendto(back, (HOST, gcs_port))
    got = receive(r1, 1.5) + receive(r2, 1.5)
    check(back in got, f"gcs -> bond: frame sent to the vehicle ({len(got)} copies over the links)")


def main():
    mode, ports = sys.argv[1], [int(p) for p in sys.argv[2:]]
    {"pair": pair, "stream": stream, "bond": bond}[mode](*ports)
    return 1 if FAILED else 0


if __name__ == "__main__":
    sys.exit(main())
