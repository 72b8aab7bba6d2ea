#!/usr/bin/env python3
"""Writes the fuzz targets' seed corpora, made here and now (no recorded data is committed).

Usage: make_corpus.py OUTDIR

OUTDIR/datagram: every message of pymavlink's `all` dialect with random field values as a v2
frame, as v1 where its id fits, all-zero (a v2 payload truncated to one byte), signed; then
datagrams of several frames, frames with noise around them, cut short, with a bad CRC, an
unknown msgid or unknown incompat flags.
OUTDIR/stream: byte streams of synthetic ArduPilot telemetry (tests/tools/synth.py) mixed with
v1 and signed frames, noise (start bytes included), partial and corrupted frames.
OUTDIR/config: the shipped configs (conf/*.yaml, conf/examples/*.yaml) and the malformed
configs of the unit tests (kBadCases in tests/unit/config/config_test.cpp) and of the
integration tests (MALFORMED in tests/integration/test_config.py).

Seeds are named seed-*: a rerun replaces them and leaves the files a fuzzer added beside them.
Deterministic: the same pymavlink and sources give the same files.
"""
from __future__ import annotations

import ast
import os
import random
import re
import struct
import sys
from pathlib import Path

os.environ["MAVLINK20"] = "1"
REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "tools"))

from pymavlink.dialects.v10 import all as mav1  # noqa: E402
from pymavlink.dialects.v20 import all as mav2  # noqa: E402
from pymavlink.generator.mavcrc import x25crc  # noqa: E402

import synth  # noqa: E402

UNKNOWN_MSGID = 15000   # not in the `all` dialect: its frames cannot be CRC-checked

INT_RANGES = {
    "int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-32768, 32767),
    "uint16_t": (0, 65535), "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1),
    "int64_t": (-2**63, 2**63 - 1), "uint64_t": (0, 2**64 - 1),
    "uint8_t_mavlink_version": (0, 255),
}


class Sink:
    def __init__(self):
        self.data = b""

    def write(self, b):
        self.data = bytes(b)


def field_value(rng: random.Random, ftype: str, array_len: int, zero: bool):
    def one():
        if ftype == "char":
            return b"\0" if zero else bytes([rng.randrange(32, 127)])
        if ftype in ("float", "double"):
            return 0.0 if zero else rng.uniform(-1e4, 1e4)
        lo, hi = INT_RANGES[ftype]
        return 0 if zero else rng.randint(lo, hi)
    if array_len == 0:
        return one()
    if ftype == "char":
        return b"" if zero else bytes(rng.randrange(32, 127) for _ in range(rng.randint(1, array_len)))
    return [one() for _ in range(array_len)]


def make_message(mod, cls, rng: random.Random, zero: bool = False):
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        args.append(field_value(rng, ftype, cls.array_lengths[cls.ordered_fieldnames.index(name)],
                                zero))
    return cls(*args)


def pack(mod, msg, sysid=1, compid=1, seq=0, v1=False, sign=False) -> bytes:
    link = mod.MAVLink(Sink(), srcSystem=sysid, srcComponent=compid)
    link.seq = seq
    if sign:
        link.signing.secret_key = bytes(range(32))
        link.signing.link_id = 1
        link.signing.timestamp = 0x1234567890
        link.signing.sign_outgoing = True
    link.send(msg, force_mavlink1=v1 and mod is mav2)
    return link.file.data


def raw_v2(msgid: int, payload: bytes, crc_extra: int = 0, flags: int = 0, seq: int = 0) -> bytes:
    body = bytes([0xFD, len(payload), flags, 0, seq, 1, 1,
                  msgid & 0xFF, (msgid >> 8) & 0xFF, (msgid >> 16) & 0xFF]) + payload
    crc = x25crc(body[1:])
    crc.accumulate(bytes([crc_extra]))
    return body + struct.pack("<H", crc.crc)


def noise(rng: random.Random, n: int, magic_rate: float = 0.05) -> bytes:
    """Random bytes in which a start byte (0xFD/0xFE) turns up now and then."""
    return bytes(rng.choice((0xFD, 0xFE)) if rng.random() < magic_rate else rng.randrange(256)
                 for _ in range(n))


def corrupt(rng: random.Random, frame: bytes) -> bytes:
    b = bytearray(frame)
    i = rng.randrange(1, len(b))
    b[i] ^= 1 << rng.randrange(8)
    return bytes(b)


def message_frames(rng: random.Random) -> dict:
    """name -> frame: each message type of the dialect, in its variants."""
    out = {}
    for i, (msgid, cls) in enumerate(sorted(mav2.mavlink_map.items())):
        name = cls.msgname.lower()
        out[f"v2-{name}"] = pack(mav2, make_message(mav2, cls, rng), seq=i & 0xFF)
        if i % 3 == 0:
            out[f"v2-zero-{name}"] = pack(mav2, make_message(mav2, cls, rng, zero=True))
        if i % 5 == 0:
            out[f"v2-signed-{name}"] = pack(mav2, make_message(mav2, cls, rng), sign=True)
        if msgid < 256 and msgid in mav1.mavlink_map:
            cls1 = mav1.mavlink_map[msgid]
            out[f"v1-{name}"] = pack(mav1, make_message(mav1, cls1, rng), seq=i & 0xFF, v1=True)
    return out


def datagram_seeds(frames: dict, rng: random.Random) -> dict:
    seeds = dict(frames)
    pool = list(frames.values())
    for k in range(40):
        picked = rng.sample(pool, rng.randint(2, 8))
        seeds[f"multi-{k:02d}"] = b"".join(picked)
    for k in range(20):
        f = rng.choice(pool)
        seeds[f"noise-{k:02d}"] = noise(rng, rng.randint(1, 30)) + f + noise(rng, rng.randint(0, 30))
        g = rng.choice(pool)
        seeds[f"cut-{k:02d}"] = g[:rng.randrange(1, len(g))] + rng.choice(pool)
        seeds[f"badcrc-{k:02d}"] = corrupt(rng, rng.choice(pool)) + rng.choice(pool)
    seeds["unknown-id"] = raw_v2(UNKNOWN_MSGID, bytes(range(20)))
    seeds["unknown-id-then-known"] = raw_v2(UNKNOWN_MSGID, bytes(20)) + pool[0]
    seeds["unknown-id-hiding-known"] = (raw_v2(UNKNOWN_MSGID, bytes(3) + pool[0] + bytes(3)))
    seeds["unknown-flags"] = raw_v2(0, bytes(9), mav2.mavlink_map[0].crc_extra, flags=0x02)
    seeds["empty"] = b""
    return seeds


def stream_seeds(frames: dict, rng: random.Random) -> dict:
    seeds = {}
    pool = list(frames.values())
    telemetry = [f for _, f in synth.ardupilot_stream(seconds=4, seed=3)]
    pos = 0
    for k in range(24):
        parts = []
        size = 0
        while size < 1000 and pos < len(telemetry):
            r = rng.random()
            if r < 0.08:
                part = noise(rng, rng.randint(1, 40), magic_rate=0.2)
            elif r < 0.12:
                f = rng.choice(pool)
                part = f[:rng.randrange(1, len(f))]              # cut short
            elif r < 0.16:
                part = corrupt(rng, telemetry[pos])
                pos += 1
            elif r < 0.22:
                part = rng.choice(pool)                          # v1, signed, zero, rare ids
            else:
                part = telemetry[pos]
                pos += 1
            parts.append(part)
            size += len(part)
        seeds[f"telemetry-{k:02d}"] = b"".join(parts)
    seeds["clean-telemetry"] = b"".join(telemetry[:40])
    for name in ("v2-heartbeat", "v1-heartbeat", "v2-signed-heartbeat", "v2-zero-command_long",
                 "v2-param_value", "v1-param_value"):
        if name in frames:
            seeds[name] = frames[name]
    return seeds


C_STRING = r'"(?:[^"\\]|\\.)*"'


def c_unescape(lit: str) -> str:
    body = lit[1:-1]
    return body.encode("latin-1", "backslashreplace").decode("unicode_escape")


def unit_test_bad_configs() -> dict:
    """The YAML texts of kBadCases in config_test.cpp: {"Label", "yaml" GCS "yaml", "error"}."""
    src = (REPO / "tests" / "unit" / "config" / "config_test.cpp").read_text()
    macros = {}
    for m in re.finditer(r"#define (\w+)\s*\\\n((?:.*\\\n)*.*\n)", src):
        macros[m.group(1)] = "".join(c_unescape(s) for s in re.findall(C_STRING, m.group(2)))
    table = src[src.index("kBadCases[] = {"):]
    table = table[:table.index("\n};")]
    out = {}
    # One case: '{' label ',' yaml-parts ',' error-parts '}' where parts are literals or macros.
    token = rf"{C_STRING}|\b(?:{'|'.join(macros) or 'NO_MACRO'})\b"
    for case in re.finditer(rf"\{{\s*({C_STRING})\s*,((?:\s*(?:{token}))+)\s*,", table):
        label = c_unescape(case.group(1))
        parts = re.findall(token, case.group(2))
        out[label] = "".join(macros[p] if p in macros else c_unescape(p) for p in parts)
    return out


def integration_bad_configs() -> list:
    tree = ast.parse((REPO / "tests" / "integration" / "test_config.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "MALFORMED"
                                                for t in node.targets):
            return [case[0] for case in ast.literal_eval(node.value)]
    return []


def config_seeds() -> dict:
    seeds = {}
    for path in sorted((REPO / "conf").glob("*.yaml")) + sorted((REPO / "conf" / "examples").glob("*.yaml")):
        seeds[f"conf-{path.stem}"] = path.read_bytes()
        # The settings a shipped config offers commented out ("#metrics:", "#  - name: x"),
        # switched on, so the seeds hold every kind of endpoint and section.
        text = path.read_text()
        offered = re.sub(r"^#(?=[a-z_]+:|  +(?:- )?[a-z_]+:)", "", text, flags=re.M)
        if offered != text:
            seeds[f"conf-{path.stem}-uncommented"] = offered.encode()
    bad = unit_test_bad_configs()
    if len(bad) < 20:
        raise SystemExit(f"found only {len(bad)} malformed configs in config_test.cpp: its "
                         f"kBadCases table changed shape; update make_corpus.py")
    for label, text in bad.items():
        seeds[f"unit-{label}"] = text.encode()
    for i, text in enumerate(integration_bad_configs()):
        seeds[f"integration-{i:02d}"] = text.encode()
    return seeds


def write(outdir: Path, target: str, seeds: dict) -> None:
    d = outdir / target
    d.mkdir(parents=True, exist_ok=True)
    for old in d.glob("seed-*"):
        old.unlink()
    for name, data in seeds.items():
        (d / f"seed-{name}").write_bytes(data)
    print(f"{d}: {len(seeds)} seeds, {sum(len(v) for v in seeds.values())} bytes")


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    outdir = Path(sys.argv[1])
    rng = random.Random(7)
    frames = message_frames(rng)
    write(outdir, "datagram", datagram_seeds(frames, rng))
    write(outdir, "stream", stream_seeds(frames, rng))
    write(outdir, "config", config_seeds())
    os.utime(outdir)   # the build's stamp: ninja compares this directory's time


if __name__ == "__main__":
    main()
