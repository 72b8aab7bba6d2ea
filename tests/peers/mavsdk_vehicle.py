#!/usr/bin/env python3
"""A vehicle made of MAVSDK's server components (PyPI `mavsdk`, its bundled C++ library), as
an independent MAVLink stack for tests/peers: it serves parameters (ParamServer), takes and
gives back missions (MissionRawServer), accepts arm and takeoff commands (ActionServer),
publishes telemetry at fixed rates (TelemetryServer) and serves files by MAVLink FTP
(FtpServer).

    mavsdk_vehicle.py --url serial:///dev/pts/7:921600 --params 300 --ftp-root DIR

It prints one JSON line `{"event": "ready", ...}` once every component is set up, one line per
event it saw (`arm`, `takeoff`, `mission`), and on SIGTERM (or stdin closing) one line
`{"event": "summary", ...}` with what it published, then exits 0. Nothing here waits without
a bound: the telemetry loop ends when asked to, and the process ends after a fixed time
(--max-seconds) whatever happens."""
from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import sys
import termios
import threading
import time

from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.cmavsdk_loader import _cmavsdk_lib
from mavsdk.plugins.action_server import ActionServer
from mavsdk.plugins.ftp_server import FtpServer
from mavsdk.plugins.mission_raw_server import MissionRawServer
from mavsdk.plugins.param_server import ParamServer
from mavsdk.plugins.telemetry_server import (AngularVelocityBody, Battery, EulerAngle, Heading,
                                             Position, TelemetryServer, VelocityNed)

# The telemetry the vehicle publishes and how often (Hz): what a GCS should receive.
RATES = {"position": 10.0, "attitude": 20.0, "battery": 2.0}


def param_name(i: int) -> str:
    return f"TEST_P{i:03d}"


def param_value(i: int) -> int:
    return i * 7 + 3


def set_timeout(mavsdk: Mavsdk, seconds: float) -> None:
    """MAVSDK's timeout for its transfers' retries (the C API has it, the Python binding does
    not wrap it)."""
    f = _cmavsdk_lib.mavsdk_set_timeout_s
    f.argtypes = [ctypes.c_void_p, ctypes.c_double]
    f.restype = None
    f(mavsdk._handle, seconds)


def calm_serial_reader(url: str) -> None:
    """MAVSDK sets its serial port to VMIN=0 VTIME=0 and polls it without waiting (epoll with
    a zero timeout, then read): its reader thread spins, a whole core. VTIME=1 makes each
    read wait up to 0.1 s for a first byte and return as soon as one comes, so the thread
    sleeps while the line is idle and nothing else changes."""
    device = url[len("serial://"):].rsplit(":", 1)[0]
    fd = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        attrs = termios.tcgetattr(fd)
        attrs[6][termios.VMIN] = 0
        attrs[6][termios.VTIME] = 1
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
    finally:
        os.close(fd)


def emit(**kw) -> None:
    sys.stdout.write(json.dumps(kw) + "\n")
    sys.stdout.flush()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--params", type=int, default=300)
    ap.add_argument("--ftp-root", required=True)
    ap.add_argument("--timeout", type=float, default=None, help="MAVSDK's transfer timeout, s")
    ap.add_argument("--max-seconds", type=float, default=600.0)
    args = ap.parse_args()

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.AUTOPILOT))
    if args.timeout:
        set_timeout(mavsdk, args.timeout)
    server = mavsdk.server_component()

    params = ParamServer(server)
    params.set_protocol(False)
    for i in range(args.params):
        params.provide_param_int(param_name(i), param_value(i))

    missions = MissionRawServer(server)
    lock = threading.Lock()

    def on_mission(result, plan, _ud):
        with lock:
            emit(event="mission", result=int(result), items=len(plan.mission_items))

    missions.subscribe_incoming_mission(on_mission)

    action = ActionServer(server)
    action.set_armable(True, True)
    action.set_disarmable(True, True)
    action.set_allow_takeoff(True)

    # The ActionServer acks arm and takeoff itself; the callbacks only record them (calling
    # set_armed_state from inside the arm callback makes it loop).
    def on_arm(result, arm, _ud):
        emit(event="arm", result=int(result), arm=bool(arm.arm))

    def on_takeoff(result, takeoff, _ud):
        emit(event="takeoff", result=int(result), takeoff=bool(takeoff))

    action.subscribe_arm_disarm(on_arm)
    action.subscribe_takeoff(on_takeoff)

    ftp = FtpServer(server)
    ftp.set_root_dir(args.ftp_root)

    telemetry = TelemetryServer(server)
    # Connected last: a GCS that asks for the parameters before they are all provided would
    # freeze the list (PARAM_PROVIDED_TOO_LATE).
    result = mavsdk.add_any_connection(args.url)
    if result != ConnectionResult.SUCCESS:
        emit(event="error", what=f"add_any_connection({args.url}): {result!r}")
        return 1
    if args.url.startswith("serial://"):
        calm_serial_reader(args.url)
    published = {k: 0 for k in RATES}
    emit(event="ready", params=args.params, rates=RATES)

    def publish(kind: str, k: int) -> None:
        if kind == "position":
            telemetry.publish_position(
                Position(47.3977 + k * 1e-7, 8.5456, 488.0 + k * 0.01, 10.0),
                VelocityNed(1.0, 0.0, 0.0), Heading(90.0))
        elif kind == "attitude":
            telemetry.publish_attitude(EulerAngle(1.0, 2.0, (k % 360) * 1.0, k * 1000),
                                       AngularVelocityBody(0.01, 0.02, 0.03))
        else:
            telemetry.publish_battery(Battery(12.4, 80.0))

    # One loop for every stream: each is due at its own multiples of its period from the
    # start, so the count published is fixed by elapsed time, not by how late a turn was.
    t0 = time.monotonic()
    deadline = t0 + args.max_seconds
    while not stop.is_set() and time.monotonic() < deadline:
        now = time.monotonic() - t0
        for kind, hz in RATES.items():
            while published[kind] <= now * hz:
                publish(kind, published[kind])
                published[kind] += 1
        nxt = min((published[k]) / hz for k, hz in RATES.items())
        stop.wait(max(0.0, min(0.05, nxt - (time.monotonic() - t0))))
    emit(event="summary", published=published, seconds=round(time.monotonic() - t0, 3))
    mavsdk.destroy()
    return 0


if __name__ == "__main__":
    sys.exit(main())
