"""A synthetic ArduPilot-like telemetry stream, for when no recording is at hand.

A copter in Loiter streams at 124 frames/s (the paper's rate) from (sysid 1, compid 1): the
message mix and rates of ArduCopter's default SRx stream rates, with slowly changing values so
payloads differ like real ones do. Frames are encoded by pymavlink (MAVLink 2, the `all`
dialect), with a proper per-source sequence counter that wraps at 256.

    from synth import ardupilot_stream
    for t_us, frame in ardupilot_stream(seconds=10, seed=1): ...
"""
from __future__ import annotations

import math
import os
import random
from typing import Iterator, Tuple

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import all as mavlink  # noqa: E402

# (rate in Hz, message builder name); the rates add up to 124 frames/s.
STREAMS = [
    (1, "heartbeat"), (25, "attitude"), (10, "global_position_int"), (10, "vfr_hud"),
    (10, "raw_imu"), (10, "scaled_pressure"), (10, "rc_channels"), (10, "servo_output_raw"),
    (10, "ahrs2"), (5, "gps_raw_int"), (5, "sys_status"), (5, "nav_controller_output"),
    (5, "local_position_ned"), (4, "vibration"), (2, "ekf_status_report"), (1, "system_time"),
    (1, "battery_status"),
]
RATE = sum(r for r, _ in STREAMS)
assert RATE == 124


class _Buffer:
    def __init__(self):
        self.data = b""

    def write(self, b):
        self.data = bytes(b)


def _builders(mav: mavlink.MAVLink, rng: random.Random):
    def build(name: str, t: float):
        ms = int(t * 1000)
        us = int(t * 1e6)
        yaw = math.sin(t / 7.0)
        lat = int((-35.3632621 + 1e-5 * math.sin(t / 30)) * 1e7)
        lon = int((149.1652374 + 1e-5 * math.cos(t / 30)) * 1e7)
        jitter = rng.random() * 1e-3
        if name == "heartbeat":
            return mav.heartbeat_encode(2, 3, 217, 5, 4)  # quad, ArduPilot, armed, Loiter
        if name == "attitude":
            return mav.attitude_encode(ms, 0.01 + jitter, -0.02, yaw, 0.001, 0.002, 0.003)
        if name == "global_position_int":
            return mav.global_position_int_encode(ms, lat, lon, 584000, 20000, 12, -7, 0, 9000)
        if name == "vfr_hud":
            return mav.vfr_hud_encode(0.3, 0.2, int(yaw * 57) % 360, 48, 20.0 + jitter, 0.0)
        if name == "raw_imu":
            return mav.raw_imu_encode(us, 3, -2, -1001, 1, 0, -1, 230, 40, -410)
        if name == "scaled_pressure":
            return mav.scaled_pressure_encode(ms, 945.2 + jitter, 0.01, 3120)
        if name == "rc_channels":
            return mav.rc_channels_encode(ms, 16, *([1500] * 4 + [1100] * 14), 255)
        if name == "servo_output_raw":
            return mav.servo_output_raw_encode(us & 0xFFFFFFFF, 0, 1510, 1490, 1505, 1495,
                                               0, 0, 0, 0)
        if name == "ahrs2":
            return mav.ahrs2_encode(0.01, -0.02, yaw, 584.0, lat, lon)
        if name == "gps_raw_int":
            return mav.gps_raw_int_encode(us, 3, lat, lon, 584000, 121, 200, 12, 9000, 14)
        if name == "sys_status":
            return mav.sys_status_encode(0x3FFFFF, 0x3FFFFF, 0x3FFFFF, 250, 12400, 1010, 87,
                                         0, 0, 0, 0, 0, 0)
        if name == "nav_controller_output":
            return mav.nav_controller_output_encode(0.01, -0.02, 90, 90, 0, 0.0, 0.0, 0.0)
        if name == "local_position_ned":
            return mav.local_position_ned_encode(ms, 1.0, 2.0, -20.0, 0.1, 0.0, 0.0)
        if name == "vibration":
            return mav.vibration_encode(us, 2.1, 2.3, 3.9, 0, 0, 0)
        if name == "ekf_status_report":
            return mav.ekf_status_report_encode(0x3FF, 0.1, 0.1, 0.1, 0.05, 0.0)
        if name == "system_time":
            return mav.system_time_encode(1700000000000000 + us, ms)
        if name == "battery_status":
            return mav.battery_status_encode(0, 1, 3, 2500, [4100, 4100, 4100] + [65535] * 7,
                                             1010, 800, 500, 87)
        raise ValueError(name)
    return build


def ardupilot_stream(seconds: float, seed: int = 1, sysid: int = 1, compid: int = 1,
                     start_us: int = 0) -> Iterator[Tuple[int, bytes]]:
    """Yields (timestamp_us, frame) for `seconds` of telemetry, in time order."""
    rng = random.Random(seed)
    buf = _Buffer()
    mav = mavlink.MAVLink(buf, srcSystem=sysid, srcComponent=compid)
    build = _builders(mav, rng)
    events = []
    for rate, name in STREAMS:
        period = 1.0 / rate
        phase = rng.random() * period
        n = int(seconds * rate)
        events.extend((phase + k * period, name) for k in range(n) if phase + k * period < seconds)
    events.sort()
    for t, name in events:
        msg = build(name, t)
        frame = msg.pack(mav)
        mav.seq = (mav.seq + 1) % 256
        yield start_us + int(t * 1e6), frame


if __name__ == "__main__":
    frames = list(ardupilot_stream(2.0))
    print(f"{len(frames)} frames in 2 s ({len(frames) / 2:.0f}/s)")
