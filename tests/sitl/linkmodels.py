#!/usr/bin/env python3
"""The links of the SITL rig, in one process, each recording exactly what it carried and what
it dropped:

  SITL --pty-- wire --pty-- air mavbond --pty-- SiK radio model --pty-- ground mavbond
                                        --udp-- LTE model (linkemu) --udp--

    linkmodels.py --spec SPEC.json --records DIR

SPEC.json: {"seed": N, "lte": {"listen": "127.0.0.1:P", "forward": "127.0.0.1:Q"}}.

- wire: two pseudo-terminal pairs joined master to master (a null-modem cable): SITL's UART
  and the air gateway's `autopilot` UART. It records every frame each way.
- radio: a pair of SiK radios (SiK firmware 2.x, ECC on, MAVLink framing on) between the
  air gateway's `sik` UART and the ground gateway's, each on its own pseudo-terminal. Each
  radio reads its host's serial line at 57600 baud (5,760 B/s: a faster writer waits in the
  pty, as at a real UART), keeps what it read in its serial buffer (SiK's RX_BUFF_MAX, 1,850
  bytes on the Si1000 radios) and loses a frame that does not fit (whole frames: with MAVLink
  framing SiK sends whole frames, and a frame cut in two would be lost anyway). The two radios
  share the air (TDM): 57,600 bit/s, about 90 % of it payload in one direction without ECC and
  half that with ECC (SiK's documentation: "ECC ... halves your available data bandwidth"):
  3,240 B/s for both directions together, the oldest waiting frame first. A frame aired while
  the radio is cut is lost. Like SiK, a radio answers each HEARTBEAT its host sends with a
  RADIO_STATUS into the serial stream towards that host: MAVLink 1, system 51 ('3'),
  component 68 ('D'), txbuf the free share of its serial buffer in SiK's 8-byte steps, rssi
  and noise of its own (no signal while cut: rssi at the noise floor, remrssi 0).
- lte: one link of tests/tools/linkemu.py in this process: 60 ms +- 15 ms each way, 1 % loss
  each way, seeded; cut (every datagram dropped, both ways, from the command on) and NAT
  rebinding (the ground hears it from a new source port) on command.

On start it prints one JSON line: the pty paths, the LTE model's addresses, and the clocks
(`mono`, `wall`: time.monotonic() and time.time() at one instant; every time recorded is
time.monotonic()). Commands, one per line on stdin: `cut radio`, `restore radio`,
`cut lte`, `restore lte`, `rebind lte`, `stop`; each is answered by a JSON line once taken,
with its time. At stop (or end of input) the records are complete in DIR:
  wire.jsonl   {"dir": "up"|"down", "t", "hex"}   up: SITL -> air gateway
  radio.jsonl  {"dir", "t_in", "t_air" (when it went on air), "t_out" (null when lost),
               "fate": carried|overflow|cut, "hex"}
               and {"report": "air"|"ground", "t", "txbuf", "rssi", "remrssi"}
  lte.jsonl    {"dir", "index", "t_in", "t_out", "fate": carried|loss|outage|..., "hex"}
  up: towards the ground gateway, down: towards the air gateway."""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import select
import sys
import threading
import time
import tty
from collections import deque
from pathlib import Path
from typing import Dict, List

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import linkemu  # noqa: E402
from tlog import frame_length  # noqa: E402

SERIAL_RATE = 5760                         # B/s: 57600 baud, 8N1
AIR_RATE = 57600                           # bit/s
PAYLOAD_RATE = AIR_RATE * 0.9 / 2 / 8      # B/s of frames over the air: 3,240
BUFFER = 1850                              # SiK serial.c RX_BUFF_MAX (Si1000 radios)
LARGEST_FRAME = 280                        # MAVLink 2 with a signature
TICK = 0.004                               # s: the radio loop's longest sleep
LTE = {"delay": "60ms", "jitter": "15ms", "loss": "1%"}
RADIO_STATUS = 109
RADIO_STATUS_CRC_EXTRA = 185


class Records:
    """One JSON-lines file, kept in memory as records come and written once closed: the radio
    loop does no file I/O. (Written as they came, a write held up by the disk's writeback
    stalled the radio thread of both rigs at once for 5-9 s: no frame read or aired, no
    RADIO_STATUS, SITL's UART unread; the gateways rightly saw a dead radio.)"""

    def __init__(self, path: Path):
        self.path = path
        self.records: List[dict] = []
        self.lock = threading.Lock()

    def add(self, **record) -> None:
        with self.lock:
            self.records.append(record)

    def close(self) -> None:
        with self.lock:
            with open(self.path, "w") as f:
                for r in self.records:
                    f.write(json.dumps(r) + "\n")
            self.records = []


class Frames:
    """Splits a byte stream into MAVLink frames by the length in their headers."""

    def __init__(self):
        self.buf = bytearray()
        self.garbage = 0

    def feed(self, data: bytes) -> List[bytes]:
        self.buf += data
        out = []
        while self.buf:
            if self.buf[0] not in (0xFD, 0xFE):
                self.buf.pop(0)
                self.garbage += 1
                continue
            n = frame_length(self.buf)
            if n is None or len(self.buf) < n:
                break
            out.append(bytes(self.buf[:n]))
            del self.buf[:n]
        return out


class Pty:
    """A pseudo-terminal pair: the host gets the slave's path; this side reads and writes the
    master. The slave stays open here too, so bytes written before the host opens its device
    wait instead of failing."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.out = bytearray()           # waiting to be written to the master

    def read(self, n: int = 65536) -> bytes:
        try:
            return os.read(self.master, n)
        except (BlockingIOError, OSError):
            return b""

    def flush(self) -> None:
        if self.out:
            try:
                n = os.write(self.master, self.out)
                del self.out[:n]
            except (BlockingIOError, OSError):
                pass

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def mavlink1(seq: int, sysid: int, compid: int, msgid: int, payload: bytes, extra: int) -> bytes:
    """A MAVLink 1 frame, as SiK builds its report by hand (X.25 CRC with the crc_extra)."""
    frame = bytes([0xFE, len(payload), seq & 0xFF, sysid, compid, msgid]) + payload
    crc = 0xFFFF
    for b in frame[1:] + bytes([extra]):
        tmp = b ^ (crc & 0xFF)
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return frame + bytes([crc & 0xFF, crc >> 8])


class Radio:
    """One SiK radio: its host's serial line (a pty), its serial buffer, its reports."""

    def __init__(self, side: str, direction: str, rng: random.Random):
        self.side, self.direction = side, direction   # direction of what it airs
        self.pty = Pty()
        self.frames = Frames()
        self.queue: deque = deque()                   # (t_in, frame)
        self.level = 0
        self.line_credit = 0.0
        self.report_due = False
        self.seq = 0
        self.rng = rng
        self.rssi = 0

    def txbuf(self) -> int:
        """SiK's serial_read_space(): the free share of the buffer, in 8-byte steps."""
        return 100 * ((BUFFER - self.level) // 8) // (BUFFER // 8)


class RadioPair(threading.Thread):
    """The two radios and the air between them, and the SITL wire, in one loop."""

    def __init__(self, records: Records, wire_records: Records, seed: int):
        super().__init__(name="radio", daemon=True)
        rng = random.Random(f"sik:{seed}")
        self.air = Radio("air", "up", rng)
        self.ground = Radio("ground", "down", rng)
        self.records, self.wire_records = records, wire_records
        self.sitl, self.autopilot = Pty(), Pty()
        self.wire_frames = {"up": Frames(), "down": Frames()}
        self.cut = False
        self.credit = 0.0
        self.stop_flag = threading.Event()
        self.lock = threading.Lock()
        self.longest_turn, self.long_turns = 0.0, 0   # the loop's own stalls (over 100 ms)

    def set_cut(self, cut: bool) -> float:
        with self.lock:
            self.cut = cut
            return time.monotonic()

    def run(self) -> None:
        radios = (self.air, self.ground)
        ptys = (self.sitl, self.autopilot, self.air.pty, self.ground.pty)
        last = time.monotonic()
        while not self.stop_flag.is_set():
            # A radio's line is read only when it has room for a byte: what waits beyond
            # its rate waits in the pty (and wakes nobody meanwhile).
            readable = [self.sitl.master, self.autopilot.master]
            readable += [r.pty.master for r in radios if r.line_credit >= 1]
            select.select(readable, [p.master for p in ptys if p.out], [], TICK)
            now = time.monotonic()
            dt, last = now - last, now
            self.longest_turn = max(self.longest_turn, dt)
            self.long_turns += dt >= 0.1
            with self.lock:
                self._wire(now)
                for r in radios:
                    self._serial_in(r, dt, now)
                self._air(dt, now)
                for r in radios:
                    if r.report_due:
                        self._report(r, now)
            for p in ptys:
                p.flush()

    def _wire(self, now: float) -> None:
        for src, dst, direction in ((self.sitl, self.autopilot, "up"),
                                    (self.autopilot, self.sitl, "down")):
            data = src.read()
            if data:
                dst.out += data
                for f in self.wire_frames[direction].feed(data):
                    self.wire_records.add(dir=direction, t=now, hex=f.hex())

    def _serial_in(self, r: Radio, dt: float, now: float) -> None:
        # The UART delivers at most its line rate; a few ms of it at once at most.
        r.line_credit = min(r.line_credit + dt * SERIAL_RATE, SERIAL_RATE * 2 * TICK)
        n = int(r.line_credit)
        if n <= 0:
            return
        data = r.pty.read(n)
        r.line_credit -= len(data)
        for f in r.frames.feed(data):
            if f[0] == 0xFD and f[7:10] == b"\0\0\0" or f[0] == 0xFE and f[5] == 0:
                r.report_due = True                  # SiK: seen_mavlink on a HEARTBEAT
            if r.level + len(f) > BUFFER:
                self.records.add(dir=r.direction, t_in=now, t_out=None, fate="overflow",
                                 hex=f.hex())
            else:
                r.queue.append((now, f))
                r.level += len(f)

    def _air(self, dt: float, now: float) -> None:
        self.credit = min(self.credit + dt * PAYLOAD_RATE, LARGEST_FRAME)
        while True:
            waiting = [r for r in (self.air, self.ground) if r.queue]
            if not waiting:
                return
            r = min(waiting, key=lambda x: x.queue[0][0])
            t_in, f = r.queue[0]
            if self.credit < len(f):
                return
            r.queue.popleft()
            r.level -= len(f)
            self.credit -= len(f)
            if self.cut:
                self.records.add(dir=r.direction, t_in=t_in, t_out=None, t_air=now,
                                 fate="cut", hex=f.hex())
            else:
                other = self.ground if r is self.air else self.air
                other.pty.out += f
                self.records.add(dir=r.direction, t_in=t_in, t_out=now, t_air=now,
                                 fate="carried", hex=f.hex())

    def _report(self, r: Radio, now: float) -> None:
        r.report_due = False
        noise = 30 + r.rng.randrange(6)
        r.rssi = noise if self.cut else 150 + r.rng.randrange(20)
        other = self.ground if r is self.air else self.air
        remrssi = 0 if self.cut else other.rssi
        remnoise = 0 if self.cut else 30
        txbuf = r.txbuf()
        # RADIO_STATUS payload: rxerrors, fixed (uint16), rssi, remrssi, txbuf, noise, remnoise
        payload = (0).to_bytes(2, "little") * 2 + bytes([r.rssi, remrssi, txbuf, noise,
                                                        remnoise])
        r.pty.out += mavlink1(r.seq, 51, 68, RADIO_STATUS, payload, RADIO_STATUS_CRC_EXTRA)
        r.seq += 1
        self.records.add(report=r.side, t=now, txbuf=txbuf, rssi=r.rssi, remrssi=remrssi)

    def close(self) -> None:
        for p in (self.sitl, self.autopilot, self.air.pty, self.ground.pty):
            p.close()


class Lte:
    """The LTE link: linkemu in a thread of this process, every datagram's bytes recorded
    (linkemu records indices, fates and send times), cut and rebound on command."""

    def __init__(self, spec: dict, seed: int, records_dir: Path):
        self.group = linkemu.LinkGroup([dict(name="lte", listen=spec["listen"],
                                             forward=spec["forward"], seed=seed,
                                             record_drops=True, record_sends=True, **LTE)])
        self.link = self.group.link("lte")
        self.arrivals: Dict[str, list] = {"up": [], "down": []}
        for name, d in self.link.dirs.items():
            d.admit = self._recording(name, d, d.admit)
        self.records_dir = records_dir

    def _recording(self, name, direction, admit):
        def wrapped(data, now, rel, have_peer=True):
            self.arrivals[name].append((direction.index, now, data))
            return admit(data, now, rel, have_peer)
        return wrapped

    def set_cut(self, cut: bool) -> float:
        """From the next datagram on (both ways), everything is dropped, or nothing more."""
        now = time.monotonic()
        rel = now - self.group.t0
        for d in self.link.dirs.values():
            if cut:
                d.cfg.outage = list(d.cfg.outage) + [(rel, math.inf)]
            elif d.cfg.outage and d.cfg.outage[-1][1] == math.inf:
                start = d.cfg.outage[-1][0]
                d.cfg.outage = d.cfg.outage[:-1] + [(start, rel - start)]
        return now

    def rebind(self) -> float:
        self.group.request_rebind("lte")
        deadline = time.monotonic() + 5
        before = self.link.rebinds
        while self.link.rebinds == before and time.monotonic() < deadline:
            time.sleep(0.001)
        return time.monotonic()

    def write(self) -> None:
        t0 = self.group.t0
        fates = {(r["direction"], r["index"]): r["reason"] for r in self.link.drops()
                 if r["reason"] != "corrupted"}
        sent = {(r["direction"], r["index"]): t0 + r["sent"] for r in self.link.sends()}
        with open(self.records_dir / "lte.jsonl", "w") as f:
            for name, rows in self.arrivals.items():
                for index, t_in, data in rows:
                    key = (name, index)
                    f.write(json.dumps(dict(dir=name, index=index, t_in=t_in,
                                            t_out=sent.get(key),
                                            fate=fates.get(key, "carried" if key in sent
                                                           else "in_flight"),
                                            hex=data.hex())) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", required=True)
    ap.add_argument("--records", required=True)
    a = ap.parse_args()
    spec = json.loads(Path(a.spec).read_text())
    out_dir = Path(a.records)
    out_dir.mkdir(parents=True, exist_ok=True)
    seed = int(spec.get("seed", 1))
    radio_records = Records(out_dir / "radio.jsonl")
    wire_records = Records(out_dir / "wire.jsonl")
    radio = RadioPair(radio_records, wire_records, seed)
    lte = Lte(spec["lte"], seed, out_dir)
    lte.group.start()
    radio.start()
    link = lte.link
    say = lambda **d: (sys.stdout.write(json.dumps(d) + "\n"), sys.stdout.flush())
    say(ptys={"sitl": radio.sitl.path, "autopilot": radio.autopilot.path,
              "radio_air": radio.air.pty.path, "radio_ground": radio.ground.pty.path},
        lte={"listen": "%s:%d" % link.listen_addr, "source": "%s:%d" % link.source_addr},
        mono=time.monotonic(), wall=time.time(), payload_rate=PAYLOAD_RATE, buffer=BUFFER)
    actions = {"cut radio": lambda: radio.set_cut(True),
               "restore radio": lambda: radio.set_cut(False),
               "cut lte": lambda: lte.set_cut(True),
               "restore lte": lambda: lte.set_cut(False),
               "rebind lte": lte.rebind}
    for line in sys.stdin:
        cmd = line.strip()
        if cmd == "stop":
            break
        if cmd in actions:
            t = actions[cmd]()
            say(done=cmd, t=t, **({"source": "%s:%d" % link.source_addr}
                                  if cmd == "rebind lte" else {}))
        elif cmd:
            say(error=f"unknown command {cmd!r}")
    radio.stop_flag.set()
    radio.join(5)
    lte.group.stop()
    lte.write()
    radio_records.close()
    wire_records.close()
    radio.close()
    say(stopped=time.monotonic(), garbage={"air": radio.air.frames.garbage,
                                           "ground": radio.ground.frames.garbage,
                                           **{f"wire_{d}": p.garbage
                                              for d, p in radio.wire_frames.items()}},
        radio_loop={"longest_turn_ms": round(radio.longest_turn * 1000),
                    "long_turns": radio.long_turns})
    return 0


if __name__ == "__main__":
    sys.exit(main())
