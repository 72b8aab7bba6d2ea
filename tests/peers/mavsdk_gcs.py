#!/usr/bin/env python3
"""A ground station made of MAVSDK's client plugins (PyPI `mavsdk`), running the workload of
tests/peers against a vehicle (tests/peers/mavsdk_vehicle.py) wherever it is:

    mavsdk_gcs.py --url tcpout://127.0.0.1:P --params 300 --mission 100 \
        --ftp-file /blob.bin --ftp-expect DIR/blob.bin --download-dir DIR

Steps, in this order: find the autopilot, subscribe to its telemetry, download every
parameter, upload a mission and read it back, arm, take off, download a file by MAVLink FTP
(burst mode). One JSON line per step on stdout: {"step", "ok", "seconds", "attempts", ...};
a step that fails says why and the run stops there (exit 1).

A transfer that fails is tried once more, as whoever runs a ground station would, and both
attempts are reported ({"t": wall-clock start, "ok", "why"}): MAVSDK gives up on a transfer
when one particular frame is lost (the vehicle's MISSION_ACK that ends an upload, the answer
to FTP's terminate), whatever the link. The tests judge whether the loss explains it.

MAVSDK's blocking calls cannot be cancelled, so each runs in a thread joined with a time
limit; a step past its limit is reported as such and the process ends at once (os._exit),
leaving MAVSDK's threads behind."""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import threading
import time

from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.ftp import Ftp
from mavsdk.plugins.mission_raw import MissionItem, MissionRaw
from mavsdk.plugins.param import Param
from mavsdk.plugins.telemetry import Telemetry

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mavsdk_vehicle import param_name, param_value, set_timeout  # noqa: E402


def emit(**kw) -> None:
    sys.stdout.write(json.dumps(kw) + "\n")
    sys.stdout.flush()


def bounded(step: str, limit: float, fn):
    """fn() in a thread; (its result or None, error or None, seconds). Past the limit the
    process ends with a 'no answer' line: the call cannot be cancelled."""
    box = {}

    def run():
        try:
            box["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - reported, not swallowed
            box["error"] = f"{type(e).__name__}: {str(e).split('; params')[0][:300]}"

    t0 = time.monotonic()
    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(limit)
    seconds = round(time.monotonic() - t0, 3)
    if t.is_alive():
        emit(step=step, ok=False, seconds=seconds, why=f"no answer within {limit} s")
        os._exit(1)
    return box.get("value"), box.get("error"), seconds


def attempt(step: str, limit: float, fn, check, tries: int = 2, settle: float = 0.0):
    """Up to `tries` attempts of fn(); check(result) -> None when good, else why not.
    Before trying again, `settle` seconds: the vehicle's side of the failed transfer gives
    up by then (MAVSDK: 5 timeouts), so the next one is not taken for part of it.
    Returns (result, ok, attempts, seconds of all)."""
    attempts = []
    total = 0.0
    result = None
    for k in range(tries):
        if k:
            time.sleep(settle)
        start = time.time()
        result, error, seconds = bounded(step, limit, fn)
        total += seconds
        why = error or check(result)
        attempts.append({"t": start, "ok": why is None, "why": why, "seconds": seconds})
        if why is None:
            return result, True, attempts, round(total, 3)
    return result, False, attempts, round(total, 3)


def mission_items(n: int):
    """n waypoints, each one different in every field a transfer could mix up."""
    return [MissionItem(seq=i, frame=6, command=16, current=1 if i == 0 else 0, autocontinue=1,
                        param1=float(i % 7), param2=0.5, param3=0.0, param4=float(i),
                        x=473977000 + i * 131, y=85456000 - i * 17, z=20.0 + i * 0.25,
                        mission_type=0) for i in range(n)]


def item_tuple(m) -> tuple:
    return (m.seq, m.frame, m.command, m.current, m.autocontinue, m.param1, m.param2,
            m.param3, m.param4, m.x, m.y, m.z, m.mission_type)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--params", type=int, default=300)
    ap.add_argument("--mission", type=int, default=100)
    ap.add_argument("--ftp-file", required=True, help="path on the vehicle's FTP server")
    ap.add_argument("--ftp-expect", required=True, help="the same file, here")
    ap.add_argument("--download-dir", required=True)
    ap.add_argument("--timeout", type=float, default=None, help="MAVSDK's transfer timeout, s")
    ap.add_argument("--step-limit", type=float, default=60.0)
    args = ap.parse_args()
    limit = args.step_limit
    settle = 6 * (args.timeout or 0.5)

    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    if args.timeout:
        set_timeout(mavsdk, args.timeout)
    if mavsdk.add_any_connection(args.url) != ConnectionResult.SUCCESS:
        emit(step="connect", ok=False, why=f"add_any_connection({args.url}) failed")
        return 1
    system, error, seconds = bounded("connect", limit, lambda: mavsdk.first_autopilot(limit - 1))
    if system is None:
        emit(step="connect", ok=False, seconds=seconds, why=error or "no autopilot found")
        return 1
    emit(step="connect", ok=True, seconds=seconds, sysid=system.get_system_id())

    telemetry = Telemetry(system)
    counts = {"position": 0, "attitude": 0, "battery": 0}

    def counter(kind):
        def cb(*_):
            counts[kind] += 1
        return cb

    telemetry.subscribe_position(counter("position"))
    telemetry.subscribe_attitude_euler(counter("attitude"))
    telemetry.subscribe_battery(counter("battery"))
    t_telemetry = time.monotonic()

    # get_all_params() has no result code: the count and every value are the check.
    want = {param_name(i): param_value(i) for i in range(args.params)}
    param = Param(system)

    def params_check(p):
        got = {x.name: x.value for x in p.int_params}
        wrong = sorted(k for k in want if got.get(k) != want[k])
        return None if got == want else f"{len(got)} parameters, {len(wrong)} missing or wrong"

    params, ok, attempts, seconds = attempt("params", limit, param.get_all_params, params_check,
                                              settle=settle)
    emit(step="params", ok=ok, seconds=seconds, attempts=attempts,
         count=len(params.int_params) if params else 0)
    if not ok:
        return 1

    mission = MissionRaw(system)
    items = mission_items(args.mission)
    _, ok, attempts, seconds = attempt("mission_upload", limit,
                                       lambda: mission.upload_mission(items), lambda _: None,
                                       settle=settle)
    emit(step="mission_upload", ok=ok, seconds=seconds, attempts=attempts, items=len(items))
    if not ok:
        return 1

    def same(back):
        if [item_tuple(a) for a in back] != [item_tuple(b) for b in items]:
            return f"{len(back)} items read back, not the {len(items)} uploaded"
        return None

    back, ok, attempts, seconds = attempt("mission_download", limit, mission.download_mission,
                                          same, settle=settle)
    emit(step="mission_download", ok=ok, seconds=seconds, attempts=attempts,
         items=len(back) if back else 0)
    if not ok:
        return 1

    action = Action(system)
    for name, fn in (("arm", action.arm), ("takeoff", action.takeoff)):
        _, ok, attempts, seconds = attempt(name, limit, fn, lambda _: None, tries=1)
        emit(step=name, ok=ok, seconds=seconds, attempts=attempts)
        if not ok:
            return 1

    ftp = Ftp(system)
    os.makedirs(args.download_dir, exist_ok=True)
    local = os.path.join(args.download_dir, os.path.basename(args.ftp_file))
    with open(args.ftp_expect, "rb") as f:
        want_sha = hashlib.sha256(f.read()).hexdigest()

    def download():
        done = threading.Event()
        outcome = {}

        def on_progress(result, _progress, _ud):
            if result.name != "NEXT":
                outcome["result"] = result.name
                done.set()

        ftp.download_async(args.ftp_file, args.download_dir, True, on_progress)
        if not done.wait(limit - 1):
            raise TimeoutError("the download never ended")
        return outcome["result"]

    def ftp_check(result):
        if result != "SUCCESS":
            return f"download ended with {result}"
        with open(local, "rb") as f:
            if hashlib.sha256(f.read()).hexdigest() != want_sha:
                return "the file differs"
        return None

    _, ok, attempts, seconds = attempt("ftp", limit, download, ftp_check, settle=settle)
    emit(step="ftp", ok=ok, seconds=seconds, attempts=attempts,
         bytes=os.path.getsize(local) if os.path.exists(local) else 0, identical=ok)
    if not ok:
        return 1

    emit(step="telemetry", ok=True, seconds=round(time.monotonic() - t_telemetry, 3),
         received=dict(counts))
    emit(step="done", ok=True)
    sys.stdout.flush()
    # MAVSDK's destructor may wait on its threads; the work is done and reported.
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
