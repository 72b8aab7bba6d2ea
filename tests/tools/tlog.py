"""Read and write MAVLink telemetry logs (.tlog) and raw MAVLink byte streams (.mavlink).

A tlog record is an 8-byte big-endian microsecond timestamp followed by one MAVLink frame.
Some tlogs (MAVProxy) also hold non-MAVLink records of 9 bytes: a timestamp and one byte of
console text; and a log may end with a truncated record. A raw .mavlink file is just the
frames, concatenated, with no timestamps.

Frames are walked by the length in their header, never by decoding them:
  0xFE (v1): 6 header bytes + payload + 2 CRC bytes
  0xFD (v2): 10 header bytes + payload + 2 CRC bytes (+ 13 signature bytes if incompat flag 0x01)

CRC checks use pymavlink (x25crc and the crc_extra of the `all` dialect), independently of
the daemon's own C implementation.

Used by the integration tests and by the demo's replay tool:
    from tlog import iter_frames, is_raw, crc_ok
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from typing import Iterable, Iterator, Optional, Tuple

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
IFLAG_SIGNED = 0x01
SIGNATURE_LEN = 13
RAW_SUFFIXES = (".mavlink", ".raw", ".bin")


def frame_length(buf: bytes, pos: int = 0) -> Optional[int]:
    """Whole length of the frame starting at buf[pos] (from its header alone), or None when
    buf[pos] is not a start byte or the header is not complete yet."""
    if pos >= len(buf):
        return None
    magic = buf[pos]
    if magic == MAGIC_V1:
        if pos + 2 > len(buf):
            return None
        return 6 + buf[pos + 1] + 2
    if magic == MAGIC_V2:
        if pos + 3 > len(buf):
            return None
        n = 10 + buf[pos + 1] + 2
        if buf[pos + 2] & IFLAG_SIGNED:
            n += SIGNATURE_LEN
        return n
    return None


@dataclass(frozen=True)
class Record:
    """One record of a log. kind: "frame" (data is one whole frame), "other" (a non-MAVLink
    byte, e.g. console text), or "truncated" (the log ends inside this record)."""
    kind: str
    timestamp_us: Optional[int]
    data: bytes
    offset: int  # where the record starts in the file


def is_raw(path: str | os.PathLike) -> bool:
    """True for a raw MAVLink byte stream (no timestamps). Decided by the file name's suffix
    (.mavlink/.raw/.bin); otherwise by content: a tlog's first byte is a timestamp's high byte
    (0x00 for any date before 2540), a raw stream's first byte is a start byte."""
    p = os.fspath(path)
    if p.lower().endswith(RAW_SUFFIXES):
        return True
    if p.lower().endswith(".tlog"):
        return False
    with open(p, "rb") as f:
        head = f.read(9)
    return len(head) > 0 and head[0] in (MAGIC_V1, MAGIC_V2)


def iter_records_bytes(data: bytes, raw: bool) -> Iterator[Record]:
    """Walks the records of a log held in memory (see iter_records)."""
    pos = 0
    size = len(data)
    if raw:
        while pos < size:
            n = frame_length(data, pos)
            if n is None and data[pos] not in (MAGIC_V1, MAGIC_V2):
                yield Record("other", None, data[pos:pos + 1], pos)
                pos += 1
                continue
            if n is None or pos + n > size:
                yield Record("truncated", None, data[pos:], pos)
                return
            yield Record("frame", None, data[pos:pos + n], pos)
            pos += n
        return
    while pos < size:
        if pos + 9 > size:
            yield Record("truncated", None, data[pos:], pos)
            return
        (ts,) = struct.unpack_from(">Q", data, pos)
        body = pos + 8
        if data[body] not in (MAGIC_V1, MAGIC_V2):
            yield Record("other", ts, data[body:body + 1], pos)
            pos = body + 1
            continue
        n = frame_length(data, body)
        if n is None or body + n > size:
            yield Record("truncated", ts, data[body:], pos)
            return
        yield Record("frame", ts, data[body:body + n], pos)
        pos = body + n


def iter_records(path: str | os.PathLike, raw: Optional[bool] = None) -> Iterator[Record]:
    """Every record of a tlog (or of a raw stream when raw / is_raw(path)), in file order."""
    if raw is None:
        raw = is_raw(path)
    with open(path, "rb") as f:
        data = f.read()
    yield from iter_records_bytes(data, raw)


def iter_frames(path: str | os.PathLike, raw: Optional[bool] = None
                ) -> Iterator[Tuple[Optional[int], bytes]]:
    """(timestamp_us or None for a raw stream, frame bytes) for every whole frame of the
    file, in order. Non-frame records and a truncated tail are skipped."""
    for rec in iter_records(path, raw):
        if rec.kind == "frame":
            yield rec.timestamp_us, rec.data


# --- frame fields -------------------------------------------------------------------------

def header_len(frame: bytes) -> int:
    return 6 if frame[0] == MAGIC_V1 else 10


def msgid(frame: bytes) -> int:
    if frame[0] == MAGIC_V1:
        return frame[5]
    return frame[7] | (frame[8] << 8) | (frame[9] << 16)


def sysid(frame: bytes) -> int:
    return frame[3] if frame[0] == MAGIC_V1 else frame[5]


def compid(frame: bytes) -> int:
    return frame[4] if frame[0] == MAGIC_V1 else frame[6]


def seq(frame: bytes) -> int:
    return frame[2] if frame[0] == MAGIC_V1 else frame[4]


def payload(frame: bytes) -> bytes:
    h = header_len(frame)
    return frame[h:h + frame[1]]


def count_marker(frame: bytes) -> Optional[Tuple[int, bool]]:
    """(count, standby) of a mavbond count marker (a NAMED_VALUE_INT named mbw:LINK or
    mbs:LINK: mavbond.yaml(5), LINK ACCOUNTING), None for any other frame. A marker is the
    link's own, written by the endpoint with a counter of its own: not part of any stream."""
    if msgid(frame) != 252:
        return None
    body = payload(frame) + bytes(18)        # MAVLink 2 trims trailing zeros
    name = body[8:18].rstrip(b"\0")
    if not (name.startswith(b"mbw:") or name.startswith(b"mbs:")):
        return None
    return int.from_bytes(body[4:8], "little"), name.startswith(b"mbs:")


# --- CRC (pymavlink) ----------------------------------------------------------------------

_crc_extra: Optional[dict] = None


def crc_extras() -> dict:
    """msgid -> crc_extra, from pymavlink's `all` dialect."""
    global _crc_extra
    if _crc_extra is None:
        from pymavlink.dialects.v20 import all as dialect  # noqa: PLC0415 (lazy: slow import)
        _crc_extra = {mid: cls.crc_extra for mid, cls in dialect.mavlink_map.items()}
    return _crc_extra


def is_known(frame: bytes) -> bool:
    """Whether the `all` dialect defines this frame's message id."""
    return msgid(frame) in crc_extras()


def compute_crc(frame: bytes, extra: int) -> int:
    from pymavlink.generator.mavcrc import x25crc  # noqa: PLC0415
    h = header_len(frame)
    crc = x25crc(frame[1:h + frame[1]])
    crc.accumulate(bytes([extra]))
    return crc.crc


def crc_ok(frame: bytes) -> Optional[bool]:
    """True when the frame's CRC matches (with its message's crc_extra), False when it does
    not, None when the message id is unknown to the `all` dialect (cannot be checked)."""
    extra = crc_extras().get(msgid(frame))
    if extra is None:
        return None
    h = header_len(frame)
    n = frame[1]
    if len(frame) < h + n + 2:
        return False
    (wire,) = struct.unpack_from("<H", frame, h + n)
    return compute_crc(frame, extra) == wire


# --- writing ------------------------------------------------------------------------------

def encode_tlog(records: Iterable[Tuple[int, bytes]]) -> bytes:
    """tlog bytes for (timestamp_us, frame-or-other bytes) records."""
    return b"".join(struct.pack(">Q", ts) + data for ts, data in records)


def write_tlog(path: str | os.PathLike, records: Iterable[Tuple[int, bytes]]) -> None:
    with open(path, "wb") as f:
        f.write(encode_tlog(records))


def write_raw(path: str | os.PathLike, frames: Iterable[bytes]) -> None:
    with open(path, "wb") as f:
        for fr in frames:
            f.write(fr)


if __name__ == "__main__":  # summary of the given files
    import sys
    from collections import Counter
    for p in sys.argv[1:]:
        kinds: Counter = Counter()
        bad = unknown = 0
        for rec in iter_records(p):
            kinds[rec.kind] += 1
            if rec.kind == "frame":
                ok = crc_ok(rec.data)
                bad += ok is False
                unknown += ok is None
        print(f"{p}: raw={is_raw(p)} frames={kinds['frame']} other={kinds['other']} "
              f"truncated={kinds['truncated']} bad_crc={bad} unknown_id={unknown}")
