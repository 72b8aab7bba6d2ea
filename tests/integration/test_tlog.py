"""The tlog endpoint: every routed frame, in order, in .tlog files that pymavlink's own tlog
reader (mavutil.mavlink_connection on a .tlog path) reads back; rotation by max_size and on
an autopilot reboot; a directory that cannot be written costs the log, never the routing."""
from __future__ import annotations

import re
import resource
import shutil
import time
from pathlib import Path
from typing import List, Tuple

from pymavlink import mavutil

from helpers import HOST, FrameMaker, free_port, recv_datagrams, split_stream, udp_server, udp_socket


def tlog(name: str, directory: Path, **kw) -> dict:
    return {"name": name, "type": "tlog", "directory": str(directory), **kw}


def read_tlog(path: Path) -> List[Tuple[float, bytes]]:
    """(timestamp in s, frame bytes) of every record, through pymavlink's tlog reader."""
    conn = mavutil.mavlink_connection(str(path))
    out = []
    try:
        for _ in range(1_000_000):  # bounded: far more than any test writes
            m = conn.recv_msg()
            if m is None:
                break
            assert m.get_type() != "BAD_DATA", f"{path}: unreadable record {m}"
            out.append((m._timestamp, bytes(m.get_msgbuf())))
    finally:
        conn.close()
    return out


def tlog_files(directory: Path) -> List[Path]:
    return sorted(directory.glob("*.tlog"))


class Link:
    """A test socket talking to one of the daemon's UDP servers."""

    def __init__(self, port: int):
        self.sock = udp_socket()
        self.addr = (HOST, port)

    def send(self, frame: bytes) -> None:
        self.sock.sendto(frame, self.addr)

    def recv(self, count: int, timeout: float = 5.0) -> List[bytes]:
        return [f for d in recv_datagrams(self.sock, count, timeout=timeout) for f in split_stream(d)]

    def close(self) -> None:
        self.sock.close()


def exchange(src: Link, dst: Link, frames: List[bytes]) -> None:
    """Sends frames from src one by one, each after the previous one came out at dst, so
    their order through the daemon is the order sent however slow the machine is."""
    for f in frames:
        src.send(f)
        assert dst.recv(1) == [f], "the frame must be routed before the next is sent"


def test_every_routed_frame_in_order_with_timestamps(start_daemon, tmp_path):
    logdir = tmp_path / "logs" / "flight"  # created by the daemon
    gcs_port, veh_port = free_port(), free_port()
    t_start = time.time()
    d = start_daemon([udp_server("gcs", gcs_port), udp_server("veh", veh_port),
                      tlog("flightlog", logdir)])
    vehicle, gcs = Link(veh_port), Link(gcs_port)
    vm, gm = FrameMaker(1, 1), FrameMaker(255, 190)
    sent: List[bytes] = []
    try:
        # The vehicle speaks first: with no GCS yet its heartbeat goes to the log alone.
        hb = vm.heartbeat()
        vehicle.send(hb)
        sent.append(hb)
        d.wait_log(r"new peer")
        ghb = gm.heartbeat(6)
        exchange(gcs, vehicle, [ghb])
        sent.append(ghb)
        telemetry = vm.telemetry(200)
        exchange(vehicle, gcs, telemetry)
        sent += telemetry
        # Targeted frames go where their target was heard, and to the log too.
        cmd = gm.command_long(1, 1)
        exchange(gcs, vehicle, [cmd])
        param = gm.param_request_read(1, 1)
        exchange(gcs, vehicle, [param])
        ack = vm.pack(vm.mod.MAVLink_command_ack_message(400, 0, 0, 0, 255, 190))
        exchange(vehicle, gcs, [ack])
        sent += [cmd, param, ack]
        # Nothing came back to the sockets that should not get it (no echo, no extra copy).
        assert vehicle.recv(1, timeout=0.3) == [] and gcs.recv(1, timeout=0.3) == []
    finally:
        vehicle.close()
        gcs.close()
    assert d.stop() == 0
    t_stop = time.time()

    files = tlog_files(logdir)
    assert len(files) == 1, f"one file per start, got {files}"
    assert files[0].name[:4].isdigit() and files[0].name.endswith(".tlog")
    records = read_tlog(files[0])
    frames = [f for _, f in records]
    print(f"\n{files[0].name}: {len(records)} records, {files[0].stat().st_size} bytes")
    assert frames == sent, "the log must hold every routed frame, in order, byte-identical"
    stamps = [t for t, _ in records]
    assert stamps == sorted(stamps), "timestamps never go back"
    assert t_start - 1 <= stamps[0] and stamps[-1] <= t_stop + 1, \
        f"timestamps {stamps[0]}..{stamps[-1]} outside the run {t_start}..{t_stop}"
    st = d.final_stats()["flightlog"]
    assert st["tx_frames"] == len(sent) and st["tx_dropped"] == 0 and st["tx_errors"] == 0
    assert st["rx_frames"] == 0, "a log never receives"
    assert "closed" in d.log() and str(files[0]) in d.log()


def test_rotation_by_size_keeps_every_frame(start_daemon, tmp_path):
    logdir = tmp_path / "logs"
    gcs_port, veh_port = free_port(), free_port()
    d = start_daemon([udp_server("gcs", gcs_port), udp_server("veh", veh_port),
                      tlog("flightlog", logdir, max_size="4KiB")])
    vehicle, gcs = Link(veh_port), Link(gcs_port)
    vm = FrameMaker(1, 1)
    try:
        gcs.send(FrameMaker(255, 190).heartbeat(6))
        d.wait_log(r"new peer")
        telemetry = vm.telemetry(600)
        for i in range(0, len(telemetry), 50):  # in bursts, each routed before the next
            for f in telemetry[i:i + 50]:
                vehicle.send(f)
            assert len(gcs.recv(len(telemetry[i:i + 50]))) == len(telemetry[i:i + 50])
    finally:
        vehicle.close()
        gcs.close()
    assert d.stop() == 0
    files = tlog_files(logdir)
    sizes = [p.stat().st_size for p in files]
    print(f"\n{len(files)} files, sizes {sizes}")
    assert len(files) >= 6, "about 30 KB of records in files of at most 4 KiB"
    assert all(0 < s <= 4096 for s in sizes)
    frames = [f for p in files for _, f in read_tlog(p)]
    assert frames[0] == FrameMaker(255, 190).heartbeat(6)
    assert frames[1:] == telemetry, "the files together hold every frame, in order"


def test_new_file_when_the_autopilot_reboots(start_daemon, tmp_path):
    logdir = tmp_path / "logs"
    veh_port = free_port()
    d = start_daemon([udp_server("veh", veh_port), tlog("flightlog", logdir)])
    vehicle = Link(veh_port)
    vm = FrameMaker(1, 1)

    def system_time(boot_ms: int) -> bytes:
        return vm.pack(vm.mod.MAVLink_system_time_message(int(time.time() * 1e6), boot_ms))

    # Up for 100 s, then a reboot: time_boot_ms starts again near 0. A copy arriving 2 s late
    # on a slower link is not a reboot.
    before = [system_time(100_000), vm.attitude(100_100), system_time(101_000),
              system_time(99_000)]
    after = [system_time(1_500), vm.attitude(1_600), system_time(2_500)]
    try:
        for f in before + after:
            vehicle.send(f)
            time.sleep(0.02)
        deadline = time.monotonic() + 10
        while len(tlog_files(logdir)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        vehicle.close()
    assert d.stop() == 0
    files = tlog_files(logdir)
    assert len(files) == 2, f"one file before the reboot, one after: {files}"
    assert [f for _, f in read_tlog(files[0])] == before
    assert [f for _, f in read_tlog(files[1])] == after
    assert "autopilot rebooted" in d.log()


def test_unwritable_directory_is_reported_and_routing_goes_on(start_daemon, tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the log directory should be\n")
    logdir = blocker / "logs"  # ENOTDIR whoever runs the test, root included
    gcs_port, veh_port = free_port(), free_port()
    d = start_daemon([udp_server("gcs", gcs_port), udp_server("veh", veh_port),
                      tlog("flightlog", logdir)])
    text = d.wait_log(r"\[tlog:flightlog\] cannot create directory")
    line = next(l for l in text.splitlines() if "[tlog:flightlog]" in l)
    print("\n" + line)
    assert str(logdir) in line and "Not a directory" in line
    vehicle, gcs = Link(veh_port), Link(gcs_port)
    vm = FrameMaker(1, 1)
    try:
        gcs.send(FrameMaker(255, 190).heartbeat(6))
        d.wait_log(r"new peer", count=1)
        telemetry = vm.telemetry(100)
        exchange(vehicle, gcs, telemetry)
        st = d.settle_stats(lambda s: s["flightlog"]["tx_dropped"], timeout=5)
    finally:
        vehicle.close()
        gcs.close()
    print("flightlog:", st["flightlog"])
    assert st["gcs"]["tx_frames"] == len(telemetry), "the other endpoints keep routing"
    assert st["flightlog"]["tx_dropped"] == len(telemetry) + 1
    assert st["flightlog"]["tx_frames"] == 0 and st["flightlog"]["tx_errors"] >= 1
    assert d.stop() == 0
    assert len(re.findall(r"\[tlog:flightlog\] cannot", d.log())) == 1, "logged once, not per retry"


def test_directory_removed_while_running(start_daemon, tmp_path):
    logdir = tmp_path / "logs"
    gcs_port, veh_port = free_port(), free_port()
    d = start_daemon([udp_server("gcs", gcs_port), udp_server("veh", veh_port),
                      tlog("flightlog", logdir)])
    vehicle, gcs = Link(veh_port), Link(gcs_port)
    vm = FrameMaker(1, 1)
    try:
        gcs.send(FrameMaker(255, 190).heartbeat(6))
        d.wait_log(r"new peer")
        exchange(vehicle, gcs, vm.telemetry(20))
        shutil.rmtree(logdir)
        # The writer notices within its check period while frames keep coming.
        deadline = time.monotonic() + 10
        while "was removed" not in d.log() and time.monotonic() < deadline:
            exchange(vehicle, gcs, [vm.heartbeat()])
            time.sleep(0.1)
        text = d.wait_log(r"\[tlog:flightlog\] .*was removed", timeout=1)
        exchange(vehicle, gcs, vm.telemetry(20))
        st = d.settle_stats(lambda s: s["flightlog"]["tx_dropped"], timeout=5)
    finally:
        vehicle.close()
        gcs.close()
    print("\n" + next(l for l in text.splitlines() if "was removed" in l))
    print("flightlog:", st["flightlog"])
    assert st["flightlog"]["tx_dropped"] >= 20 and st["flightlog"]["tx_errors"] >= 1
    assert d.stop() == 0
    assert not logdir.exists(), "a vanished directory is not silently recreated"



def test_write_errors_then_writing_again(start_daemon, tmp_path):
    """The disk refuses writes mid-flight, then takes them again. The refusal is a file size
    limit put on the running daemon (RLIMIT_FSIZE through prlimit: EFBIG, and SIGXFSZ, which
    must not kill it), the same write-error path as a full disk (ENOSPC) without needing to
    mount one. One log line per change of state; the lost frames are counted; routing goes on;
    the file stays whole records (pymavlink reads every one) and holds exactly the frames
    counted as written, the ones after the recovery included."""
    logdir = tmp_path / "logs"
    gcs_port, veh_port = free_port(), free_port()
    d = start_daemon([udp_server("gcs", gcs_port), udp_server("veh", veh_port),
                      tlog("flightlog", logdir)])
    pid = d.proc.pid
    limit = 16 * 1024
    vehicle, gcs = Link(veh_port), Link(gcs_port)
    vm = FrameMaker(1, 1)
    try:
        hello = FrameMaker(255, 190).heartbeat(6)
        gcs.send(hello)
        d.wait_log(r"new peer")
        d.wait_log(r"\[tlog:flightlog\] writing ")
        resource.prlimit(pid, resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
        refused = vm.telemetry(1000)  # about 50 kB of records: the limit is hit on the way
        exchange(vehicle, gcs, refused)
        text = d.wait_log(r"\[tlog:flightlog\] cannot write")
        st = d.settle_stats(lambda s: s["flightlog"]["tx_dropped"], timeout=5)
        assert st["flightlog"]["tx_dropped"] > 0 and st["flightlog"]["tx_errors"] >= 1
        resource.prlimit(pid, resource.RLIMIT_FSIZE,
                         (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
        after = vm.telemetry(200)
        exchange(vehicle, gcs, after)
        d.wait_log(r"\[tlog:flightlog\] writing again")
    finally:
        vehicle.close()
        gcs.close()
    assert d.stop() == 0, "SIGXFSZ did not kill it"
    final = d.final_stats()["flightlog"]
    log = d.log()
    print("\n" + next(l for l in text.splitlines() if "cannot write" in l))
    files = tlog_files(logdir)
    records = [f for path in files for _, f in read_tlog(path)]
    print(f"flightlog: {final}; {len(files)} file(s), {sum(p.stat().st_size for p in files)} "
          f"bytes, {len(records)} records")
    # and the GCS heartbeat that made the vehicle routable
    assert final["tx_frames"] + final["tx_dropped"] == len(refused) + len(after) + 1
    assert len(records) == final["tx_frames"], "the file holds exactly the frames counted"
    assert records[-len(after):] == after, "the frames after the recovery are all there"
    # The whole records that fitted under the limit stayed, in order (a cut one went).
    before = records[:-len(after)]
    routed = iter([hello] + refused)
    assert before and all(any(r == f for f in routed) for r in before)
    assert len(re.findall(r"\[tlog:flightlog\] cannot write", log)) == 1
    assert len(re.findall(r"\[tlog:flightlog\] writing again", log)) == 1
    assert d.final_stats()["gcs"]["tx_frames"] == len(refused) + len(after)
