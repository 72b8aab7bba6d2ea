"""Bonding milestone: real mavbond gateways with the dedup / linkswitch plugins, real link
emulators (tests/tools/linkemu.py processes) and real UDP sockets on 127.0.0.1.

Ground truth comes from the emulators' drop logs (--log-drops: which datagram index each link
lost) or from the test's own deterministic dropping, never from the daemon's counters. Each
test prints its figures (run with -s to see them).

Durations are chosen so the whole file runs in a few minutes on 2 cores; each test says how
long it streams and why that is enough. Nothing here depends on the machine keeping time:
dedup matches copies by identity, so a late emulator or a busy CPU changes when frames
arrive, never which ones are delivered."""
from __future__ import annotations

import re
import random
import subprocess
import time
from collections import Counter

import pytest

from helpers import HOST, FrameMaker, free_port, udp_client, udp_server
from bonding_helpers import (Receiver, carried, content_key, gcs_hello, sniffer, multiset_diff, paced_events,
                             paced_send, timestamp_of, tlog, with_seq, Ticker)
from synth import ardupilot_stream


def ground_gateway(lab, links, filters, name="ground", gcs_port=None, **top):
    """A gateway with one UDP server link per port in `links` (bond `vehicle`) and a `gcs`
    UDP server. Returns (gateway, gcs port)."""
    gcs_port = gcs_port or free_port()
    eps = [udp_server(n, p, bond="vehicle") for n, p in links.items()]
    eps.append(udp_server("gcs", gcs_port))
    # Delivered frames are known by their bytes here: no renumbering (test_renumber's part).
    g = lab.gateway(eps, bonds=[{"name": "vehicle", "tx": "broadcast", "renumber": False}],
                    filters=filters,
                    name=name, **top)
    return g, gcs_port


def schedule_of(seconds, seed=1):
    return [(t / 1e6, f) for t, f in ardupilot_stream(seconds, seed)]


def reached(n, *dropped_sets):
    """Indices 0..n-1 that at least one link forwarded."""
    return [i for i in range(n) if not all(i in d for d in dropped_sets)]


# --- (1) two lossy links, air and ground gateways -----------------------------------------

def test_two_lossy_links_delivered_loss_is_the_product(lab):
    """124 frames/s for 60 s (7,440 frames) from a vehicle through an air-side mavbond, two
    links with 1% loss each (10 ms and 40 ms one-way), a ground-side mavbond with dedup, to a
    GCS. Delivered loss is within 3x of the product of the links' measured loss rates, no
    duplicate is delivered and no frame that reached the ground gateway on some link is lost.
    The seeds are fixed: the emulators' loss decisions depend only on (seed, index). What each
    link carried is what its emulator's tee saw (the gateways' own count markers go between)."""
    seconds = 60
    p_auto, la, lb, ga, gb, sa, sb = (free_port() for _ in range(7))
    ground, gcs_port = ground_gateway(lab, {"radio": ga, "lte": gb},
                                      [{"plugin": "dedup", "bonds": ["vehicle"]}])
    sniff_a, sniff_b = sniffer(lab, sa), sniffer(lab, sb)
    emu_a = lab.emu("radio", la, ga, seed=11, loss="1%", delay="10ms", forward=f"{HOST}:{sa}")
    emu_b = lab.emu("lte", lb, gb, seed=22, loss="1%", delay="40ms", forward=f"{HOST}:{sb}")
    air = lab.gateway([udp_server("autopilot", p_auto),
                       udp_client("radio", la, bond="ground"),
                       udp_client("lte", lb, bond="ground")],
                      bonds=[{"name": "ground", "tx": "broadcast", "renumber": False}],
                      filters=[{"plugin": "dedup", "bonds": ["ground"]}], name="air")
    gcs = lab.sock()
    rx = Receiver(gcs, hello_port=gcs_port)
    vehicle = lab.sock()
    sched = schedule_of(seconds, seed=5)
    n = len(sched)
    paced_send(sched, [(vehicle, (HOST, p_auto))])
    rx.wait_quiet(0.5)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    ca, cb = emu_a.stop(), emu_b.stop()
    air_stats, ground_stats = air.stats(), ground.stats()

    frames = [f for _, f in sched]
    ka, kb = set(carried(frames, sniff_a.stop())), set(carried(frames, sniff_b.stop()))
    da, db = set(range(n)) - ka, set(range(n)) - kb
    # Every frame went on both links: what a link did not carry, its emulator dropped.
    for c, d, dropped, name in ((ca, da, emu_a.dropped(), "radio"), (cb, db, emu_b.dropped(), "lte")):
        assert c["up"]["received"] == air_stats[name]["tx_frames"] and len(d) <= len(dropped), \
            f"the air gateway did not put every frame on {name}: {c['up']}"
    ok = reached(n, da, db)
    pa, pb = len(da) / n, len(db) / n
    missing, extra = multiset_diff((frames[i] for i in ok), got)
    delivered_loss = (n - len(got)) / n
    print(f"\n[1] {n} frames in {seconds} s; radio lost {len(da)} ({pa:.3%}), lte lost {len(db)} "
          f"({pb:.3%}); lost on both: {n - len(ok)}; product {pa * pb:.5%} "
          f"(expected {pa * pb * n:.2f} frames)")
    print(f"[1] delivered {len(got)}; delivered loss {delivered_loss:.5%} "
          f"({n - len(got)} frames); duplicates delivered {sum(extra.values())}; "
          f"lost although they reached the ground: {sum(missing.values())}")
    print(f"[1] ground radio rx={ground_stats['radio']['rx_frames']} lte "
          f"rx={ground_stats['lte']['rx_frames']} gcs tx={ground_stats['gcs']['tx_frames']}; "
          f"air autopilot rx={air_stats['autopilot']['rx_frames']}")
    assert not extra, f"{sum(extra.values())} duplicate frames delivered"
    assert not missing, f"{sum(missing.values())} frames that reached the ground were lost"
    assert delivered_loss <= 3 * pa * pb, (delivered_loss, pa * pb)


# --- config errors ------------------------------------------------------------------------

def _run_check(mavbond_bin, tmp_path, plugin_dir, text, check):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    args = [mavbond_bin, "-c", str(path), "--plugin-dir", plugin_dir]
    if check:
        args.append("--check-config")
    return path, subprocess.run(args, capture_output=True, text=True, timeout=10)


BOND_EPS = ("endpoints:\n"
            "  - {name: a, type: udp, mode: server, address: 127.0.0.1:%d, bond: vehicle}\n"
            "  - {name: b, type: udp, mode: server, address: 127.0.0.1:%d, bond: vehicle}\n"
            "bonds:\n"
            "  - {name: vehicle, tx: broadcast}\n")


@pytest.mark.parametrize("check", [True, False], ids=["check-config", "run"])
def test_unknown_plugin_option_exits_78_with_position(mavbond_bin, tmp_path, plugin_dir, check):
    text = (BOND_EPS % (free_port(), free_port()) +
            "filters:\n"
            "  - {plugin: dedup, bonds: [vehicle], window: 1s}\n"
            "  - {plugin: linkswitch, bonds: [vehicle], swich_after: 1s}\n")
    path, r = _run_check(mavbond_bin, tmp_path, plugin_dir, text, check)
    print(f"\n[config] exit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == 78
    # the line of the second filter, the column of the bad key
    lines = text.splitlines()
    line = next(i for i, l in enumerate(lines) if "swich_after" in l)
    m = re.search(re.escape(str(path)) + r":(\d+):(\d+)", r.stderr)
    assert m, r.stderr
    assert int(m.group(1)) == line + 1, r.stderr
    assert int(m.group(2)) == lines[line].index("swich_after") + 1, r.stderr
    assert "swich_after" in r.stderr


@pytest.mark.parametrize("check", [True, False], ids=["check-config", "run"])
def test_missing_plugin_file_exits_78_naming_the_file(mavbond_bin, tmp_path, plugin_dir, check):
    text = (BOND_EPS % (free_port(), free_port()) +
            "filters:\n"
            "  - {plugin: nosuchfilter, bonds: [vehicle]}\n")
    path, r = _run_check(mavbond_bin, tmp_path, plugin_dir, text, check)
    print(f"\n[config] exit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == 78
    assert "nosuchfilter.so" in r.stderr, r.stderr
    line = next(i for i, l in enumerate(text.splitlines()) if "nosuchfilter" in l) + 1
    assert re.search(re.escape(str(path)) + rf":{line}:\d+", r.stderr), r.stderr


# --- (2) byte-identical repeats at 1,000 frames/s -----------------------------------------

def identical_cycle():
    """256 frames (seq 0..255) without timestamps: HEARTBEAT, SYS_STATUS, VFR_HUD with fixed
    values. Sent again and again, every instance of seq k is byte-identical."""
    m = FrameMaker(1, 1)
    out = []
    for k in range(256):
        m.mav.seq = k
        if k % 3 == 0:
            out.append(m.heartbeat())
        elif k % 3 == 1:
            out.append(m.sys_status())
        else:
            out.append(m.pack(m.mod.MAVLink_vfr_hud_message(0.5, 0.4, 90, 48, 20.0, 0.1)))
    assert len(set(out)) == 256
    return out


@pytest.mark.parametrize("variant", ["clean", "lossy_skewed", "lossy_skewed_mixed"])
def test_identical_repeats_at_1000_per_second(lab, variant):
    """1,000 frames/s of one 256-frame cycle of byte-identical frames, so the same bytes recur
    every 0.256 s, well inside the dedup window. `clean`: two perfect links, 4 s (4,000
    instances, 15 cycles). `lossy_skewed`: 5% loss on each link and the second link 300 ms
    behind the first (more than one cycle: when its copy of instance i arrives, the first link
    already delivered instance i+256 with the same bytes), window 2 s (the default), 8 s
    (8,000 instances). `lossy_skewed_mixed`: the same, but every 4th frame is unique (a
    VFR_HUD whose altitude counts up), as real telemetry has unique frames next to repeated
    ones. Every instance that reached the gateway on some link (ground truth: the
    emulators' drop logs) is delivered once: counted per distinct frame, nothing missing,
    nothing extra."""
    seconds = 4 if variant == "clean" else 8
    lossy = variant.startswith("lossy_skewed")
    la, lb, ga, gb = (free_port() for _ in range(4))
    g, gcs_port = ground_gateway(lab, {"link_a": ga, "link_b": gb},
                                 [{"plugin": "dedup", "bonds": ["vehicle"], "window": "2s"}])
    opts_a = {"loss": "5%"} if lossy else {}
    opts_b = {"loss": "5%", "delay": "300ms"} if lossy else {}
    emu_a = lab.emu("a", la, ga, seed=3, **opts_a)
    emu_b = lab.emu("b", lb, gb, seed=4, **opts_b)
    gcs = lab.sock()
    rx = Receiver(gcs, hello_port=gcs_port)
    cycle = identical_cycle()
    n = 1000 * seconds
    frames = [cycle[i % 256] for i in range(n)]
    if variant.endswith("mixed"):
        m = FrameMaker(1, 1)
        for i in range(3, n, 4):
            m.mav.seq = i % 256
            frames[i] = m.pack(m.mod.MAVLink_vfr_hud_message(0.5, 0.4, 90, 48, float(i), 0.1))
    sched = [(i / 1000.0, frames[i]) for i in range(n)]
    sa, sb = lab.sock(), lab.sock()
    paced_send(sched, [(sa, (HOST, la)), (sb, (HOST, lb))])
    rx.wait_quiet(0.6)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    ca, cb = emu_a.stop(), emu_b.stop()
    st = g.stats()
    assert ca["up"]["received"] == n and cb["up"]["received"] == n, (ca["up"], cb["up"])
    da, db = emu_a.dropped(), emu_b.dropped()
    ok = reached(n, da, db)
    want = Counter(frames[i] for i in ok)
    have = Counter(got)
    missing, extra = want - have, have - want
    print(f"\n[2 {variant}] {n} instances at 1000/s ({n // 256} cycles of 256 identical "
          f"frames); link_a lost {len(da)}, link_b lost {len(db)}, both {n - len(ok)}; "
          f"reached the gateway {len(ok)}; delivered {len(got)}; legitimate frames dropped "
          f"{sum(missing.values())}; duplicates delivered {sum(extra.values())}")
    print(f"[2 {variant}] gateway: link_a rx={st['link_a']['rx_frames']} "
          f"link_b rx={st['link_b']['rx_frames']} gcs tx={st['gcs']['tx_frames']} "
          f"tx_dropped={st['gcs']['tx_dropped']}")
    if missing or extra:  # for a closer look: what was sent, lost and delivered when
        import pickle
        (lab.workdir / "identical.pkl").write_bytes(pickle.dumps(
            dict(cycle=cycle, da=sorted(da), db=sorted(db), rx=rx.frames)))
    assert st["link_a"]["rx_frames"] == n - len(da) and st["link_b"]["rx_frames"] == n - len(db)
    assert not missing, f"{sum(missing.values())} legitimate repeats dropped"
    assert not extra, f"{sum(extra.values())} duplicates delivered"


# --- (3) one link down for 15 s -----------------------------------------------------------

def index_of(frames):
    """frame bytes -> index, for the frames that occur once in the stream."""
    c = Counter(frames)
    return {f: i for i, f in enumerate(frames) if c[f] == 1}


def test_one_link_down_for_15s_dedup_and_linkswitch(lab):
    """124 frames/s for 21 s; link A (first in the bond) is down from 3 s to 18 s after its
    emulator started; both links lose 1% and take 20 ms. Two ground gateways run side by side
    on the same frames (four emulators): one with dedup, one with linkswitch (switch_after
    1s). With dedup nothing is lost beyond link B's own loss during the outage (exactly the
    frames lost on both links). With linkswitch the switch happens within switch_after +
    100 ms of the outage start (measured from when A's first missing frame was due to the
    first frame delivered via B), and the frames lost during detection are counted."""
    seconds, switch_after = 21, 1.0
    ports = {k: free_port() for k in ("la1", "lb1", "ga1", "gb1", "la2", "lb2", "ga2", "gb2")}
    g_dd, gcs_dd = ground_gateway(lab, {"link_a": ports["ga1"], "link_b": ports["gb1"]},
                                  [{"plugin": "dedup", "bonds": ["vehicle"]}], name="dedup")
    g_ls, gcs_ls = ground_gateway(lab, {"link_a": ports["ga2"], "link_b": ports["gb2"]},
                                  [{"plugin": "linkswitch", "bonds": ["vehicle"],
                                    "switch_after": "1s"}],
                                  name="linkswitch")
    a_opts = dict(loss="1%", delay="20ms", outage="3s+15s")
    b_opts = dict(loss="1%", delay="20ms")
    emus = {"a1": lab.emu("a1", ports["la1"], ports["ga1"], seed=31, **a_opts),
            "b1": lab.emu("b1", ports["lb1"], ports["gb1"], seed=32, **b_opts),
            "a2": lab.emu("a2", ports["la2"], ports["ga2"], seed=31, **a_opts),
            "b2": lab.emu("b2", ports["lb2"], ports["gb2"], seed=32, **b_opts)}
    rx_dd = Receiver(lab.sock(), hello_port=gcs_dd)
    rx_ls = Receiver(lab.sock(), hello_port=gcs_ls)
    sched = schedule_of(seconds, seed=8)
    n = len(sched)
    frames = [f for _, f in sched]
    socks = {k: lab.sock() for k in emus}
    # Frame 0 goes on link A of the linkswitch gateway 0.3 s before everything else, so
    # link A is heard first there and is the active link from the start (linkswitch takes the
    # first link it hears). The dedup gateway gets both copies together.
    keys = list(emus)
    events = [(0.0, keys.index("a2"), frames[0])]
    events += [(0.3, keys.index(k), frames[0]) for k in ("b2", "a1", "b1")]
    events += [(t + 0.3, keys.index(k), f) for t, f in sched[1:] for k in keys]
    times = paced_events(events, [(socks[k], (HOST, emus[k].listen_port)) for k in keys])
    sent = [times[0]] + times[4 + keys.index("a2")::4]  # when each frame left for a2
    assert len(sent) == n
    rx_dd.wait_quiet(0.5)
    rx_ls.wait_quiet(0.5)
    got_dd = [(t, f) for t, f in rx_dd.frames if tlog.sysid(f) == 1]
    got_ls = [(t, f) for t, f in rx_ls.frames if tlog.sysid(f) == 1]
    rx_dd.stop()
    rx_ls.stop()
    for e in emus.values():
        e.stop()
        assert e.counters()["up"]["received"] == n

    # dedup: exactly what reached the gateway on some link
    d = {k: e.dropped() for k, e in emus.items()}
    outage = sorted(r["index"] for r in emus["a1"].drops() if r["reason"] == "outage")
    ok = reached(n, d["a1"], d["b1"])
    missing, extra = multiset_diff((frames[i] for i in ok), (f for _, f in got_dd))
    lost_in_outage_b = sum(1 for i in outage if i in d["b1"])
    print(f"\n[3 dedup] {n} frames; link A down for {len(outage)} frames "
          f"({(sent[outage[-1]] - sent[outage[0]]):.2f} s), its other losses "
          f"{len(d['a1']) - len(outage)}; link B lost {len(d['b1'])} "
          f"({lost_in_outage_b} during the outage); delivered {len(got_dd)} of {n}, lost "
          f"{n - len(got_dd)} (= lost on both links: {n - len(ok)}); missing beyond that "
          f"{sum(missing.values())}, duplicates {sum(extra.values())}")
    assert not missing and not extra

    # linkswitch
    outage2 = sorted(r["index"] for r in emus["a2"].drops() if r["reason"] == "outage")
    first_o = outage2[0]
    t_outage = sent[first_o] + 0.020  # when A's first missing frame was due at the gateway
    idx = index_of(frames)
    after = [(t, idx[f]) for t, f in got_ls if f in idx and idx[f] >= first_o]
    t_first, i_first = after[0]
    detection = t_first - t_outage
    lost_detect = [i for i in range(first_o, i_first) if i not in d["b2"]]
    log = g_ls.log()
    switch_lines = re.findall(r"active link link_a\S* -> link_b\S*: .*", log)
    missing2, extra2 = multiset_diff(frames, (f for _, f in got_ls))
    print(f"[3 linkswitch] outage from frame {first_o}; first frame delivered via link B: "
          f"{i_first}, {detection * 1000:.0f} ms after the outage start (limit "
          f"{(switch_after + 0.1) * 1000:.0f} ms); frames lost during detection that B carried: "
          f"{len(lost_detect)}; total delivered {len(got_ls)} of {n}; duplicates "
          f"{sum(extra2.values())}; log: {switch_lines}")
    assert switch_lines, log
    assert detection <= switch_after + 0.1
    assert not extra2
    # after the switch, everything B carried is delivered
    b_after = [frames[i] for i in range(i_first, n) if i not in d["b2"]]
    miss_after, _ = multiset_diff(b_after, (f for _, f in got_ls))
    assert not miss_after, f"{sum(miss_after.values())} frames lost via B after the switch"


# --- (4) corrupted on one link, clean on the other ----------------------------------------

def test_corrupted_copy_loses_to_the_clean_one(lab):
    """124 frames/s for 6 s (744 frames); link A flips one bit in 10% of its datagrams and is
    20 ms ahead of link B, so the corrupted copy always arrives first. Every frame is
    delivered exactly once, byte-identical to what was sent (the clean copy from B).
    unknown_messages: drop, because a bit flipped in the message id makes an id the gateway
    cannot CRC-check, which the default (forward) passes on."""
    la, lb, ga, gb = (free_port() for _ in range(4))
    g, gcs_port = ground_gateway(lab, {"link_a": ga, "link_b": gb},
                                 [{"plugin": "dedup", "bonds": ["vehicle"]}],
                                 unknown_messages="drop")
    emu_a = lab.emu("a", la, ga, seed=41, corrupt="10%")
    emu_b = lab.emu("b", lb, gb, seed=42, delay="20ms")
    rx = Receiver(lab.sock(), hello_port=gcs_port)
    sched = schedule_of(6, seed=4)
    n = len(sched)
    frames = [f for _, f in sched]
    sa, sb = lab.sock(), lab.sock()
    paced_send(sched, [(sa, (HOST, la)), (sb, (HOST, lb))])
    rx.wait_quiet(0.5)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    emu_a.stop()
    emu_b.stop()
    st = g.stats()
    corrupted = emu_a.corrupted()
    missing, extra = multiset_diff(frames, got)
    bad = [f for f in got if tlog.crc_ok(f) is False or f not in set(frames)]
    for f in bad:
        print(f"[4] corrupted frame delivered: msgid {tlog.msgid(f)} known {tlog.is_known(f)} "
              f"crc_ok {tlog.crc_ok(f)}: {f.hex()}")
    print(f"\n[4] {n} frames; link A corrupted {len(corrupted)}; gateway link_a "
          f"crc_errors={st['link_a']['crc_errors']} garbage_bytes={st['link_a']['garbage_bytes']} "
          f"bad_flags={st['link_a']['bad_flags']} rx_frames={st['link_a']['rx_frames']}; "
          f"delivered {len(got)}, missing {sum(missing.values())}, duplicates "
          f"{sum(extra.values())}, corrupted delivered {len(bad)}")
    assert len(corrupted) > 30
    assert not bad and not missing and not extra


# --- (5) commands through two lossy links, both sides mavbond -----------------------------

def test_commands_reach_the_autopilot_once(lab):
    """Air and ground gateways, both with dedup; two links with 5% loss in each direction
    (10 ms and 40 ms). A GCS sends 500 COMMAND_LONG (param1 = its number) at 100/s; the
    autopilot gets each one exactly once unless both links lost it (ground truth: what each
    emulator's down tee saw it carry)."""
    n_cmd = 500
    p_auto, la, lb, ga, gb, sa, sb = (free_port() for _ in range(7))
    ground, gcs_port = ground_gateway(lab, {"radio": ga, "lte": gb},
                                      [{"plugin": "dedup", "bonds": ["vehicle"]}])
    sniff_a, sniff_b = sniffer(lab, sa), sniffer(lab, sb)
    emu_a = lab.emu("radio", la, ga, seed=51, loss="5%", delay="10ms", down_tee=f"{HOST}:{sa}")
    emu_b = lab.emu("lte", lb, gb, seed=52, loss="5%", delay="40ms", down_tee=f"{HOST}:{sb}")
    air = lab.gateway([udp_server("autopilot", p_auto),
                       udp_client("radio", la, bond="ground"),
                       udp_client("lte", lb, bond="ground")],
                      bonds=[{"name": "ground", "tx": "broadcast", "renumber": False}],
                      filters=[{"plugin": "dedup", "bonds": ["ground"]}], name="air")
    vehicle = lab.sock()
    veh = FrameMaker(1, 1)
    rx_veh = Receiver(vehicle)
    ticker = Ticker(vehicle, (HOST, p_auto), lambda k: veh.heartbeat(), period=0.1)
    gcs = lab.sock()
    rx_gcs = Receiver(gcs)
    gcs_hello(gcs, gcs_port)
    deadline = time.monotonic() + 5
    # both ground links have heard the air side (each learned its peer) before commands go
    while not (ground.log().count("new peer") >= 3 and
               any(tlog.sysid(f) == 1 for _, f in rx_gcs.frames)):
        assert time.monotonic() < deadline, ground.log()
        time.sleep(0.05)
    time.sleep(0.3)
    m = FrameMaker(255, 190)
    cmds = []
    for i in range(n_cmd):
        m.mav.seq = i % 256
        cmds.append(m.pack(m.mod.MAVLink_command_long_message(
            1, 1, 400, 0, float(i), 0, 0, 0, 0, 0, 0)))
    paced_send([(i / 100.0, c) for i, c in enumerate(cmds)], [(gcs, (HOST, gcs_port))])
    rx_veh.wait_quiet(0.5)
    ticker.stop()
    got = [f for f in rx_veh.stop() if tlog.msgid(f) == 76]
    rx_gcs.stop()
    emu_a.stop(), emu_b.stop()
    da = set(range(n_cmd)) - set(carried(cmds, sniff_a.stop()))
    db = set(range(n_cmd)) - set(carried(cmds, sniff_b.stop()))
    ok = reached(n_cmd, da, db)
    count = Counter(got)
    dup = sum(c - 1 for c in count.values() if c > 1)
    missing = [i for i in ok if count[cmds[i]] == 0]
    unexpected = [i for i in range(n_cmd) if i not in set(ok) and count[cmds[i]]]
    print(f"\n[5] {n_cmd} commands; radio lost {len(da)} down, lte lost {len(db)}, both "
          f"{n_cmd - len(ok)}; the autopilot got {len(got)} ({len(count)} distinct), "
          f"duplicates {dup}, missing although a link carried them {len(missing)}")
    assert dup == 0
    assert not missing
    assert not unexpected


# --- (6) key: content, separate sequence counters -----------------------------------------

def test_key_content_with_separate_sequence_counters(lab):
    """An autopilot feeding two radios, each with its own sequence counter: the same
    messages go out on link B with seq + 77 (CRC recomputed), 15 ms after link A; each link
    loses 5% (deterministic, seeded). 124 frames/s for 6 s (744 messages). With
    dedup key: content each message that reached the gateway is delivered exactly once."""
    ga, gb = free_port(), free_port()
    g, gcs_port = ground_gateway(lab, {"link_a": ga, "link_b": gb},
                                 [{"plugin": "dedup", "bonds": ["vehicle"], "key": "content"}])
    rx = Receiver(lab.sock(), hello_port=gcs_port)
    sched = schedule_of(6, seed=6)
    n = len(sched)
    rng = random.Random(6)
    da, db, events = set(), set(), []
    for i, (t, f) in enumerate(sched):
        if rng.random() < 0.05:
            da.add(i)
        else:
            events.append((t, 0, f))
        if rng.random() < 0.05:
            db.add(i)
        else:
            events.append((t + 0.015, 1, with_seq(f, tlog.seq(f) + 77)))
    events.sort(key=lambda e: e[0])
    sa, sb = lab.sock(), lab.sock()
    paced_events(events, [(sa, (HOST, ga)), (sb, (HOST, gb))])
    rx.wait_quiet(0.5)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    ok = reached(n, da, db)
    missing, extra = multiset_diff((content_key(sched[i][1]) for i in ok),
                                   (content_key(f) for f in got))
    from_b = sum(1 for f in got if f not in {x for _, x in sched})
    print(f"\n[6] {n} messages; link A lost {len(da)}, link B {len(db)}, both {n - len(ok)}; "
          f"delivered {len(got)} ({from_b} with link B's numbering); missing "
          f"{sum(missing.values())}, duplicates {sum(extra.values())}")
    assert not missing and not extra


# --- (7) one link 2 s late: no stale sample -----------------------------------------------

STALE_AFTER = 0.25  # dedup's default stale_after


def test_late_link_never_delivers_a_stale_sample(lab):
    """Link B is 2 s behind link A; A loses 10% (deterministic). dedup with window 5s
    (covers the skew). 124 frames/s for 8 s (992 frames). No timestamped sample (time_boot_ms
    / time_usec, e.g. GLOBAL_POSITION_INT, ATTITUDE) is delivered more than stale_after
    (250 ms) behind a newer one of its (sysid, compid, msgid); frames without a timestamp that
    only B carried are still delivered, 2 s late; nothing is delivered twice."""
    ga, gb = free_port(), free_port()
    g, gcs_port = ground_gateway(lab, {"link_a": ga, "link_b": gb},
                                 [{"plugin": "dedup", "bonds": ["vehicle"], "window": "5s"}])
    rx = Receiver(lab.sock(), hello_port=gcs_port)
    sched = schedule_of(8, seed=7)
    n = len(sched)
    frames = [f for _, f in sched]
    rng = random.Random(7)
    da = {i for i in range(n) if rng.random() < 0.10}
    events = [(t, 0, f) for i, (t, f) in enumerate(sched) if i not in da]
    events += [(t + 2.0, 1, f) for t, f in sched]
    events.sort(key=lambda e: e[0])
    sa, sb = lab.sock(), lab.sock()
    paced_events(events, [(sa, (HOST, ga)), (sb, (HOST, gb))])
    rx.wait_quiet(0.5)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    newest, backwards, slightly = {}, [], 0
    for f in got:
        ts = timestamp_of(f)
        if ts is None:
            continue
        key = (tlog.sysid(f), tlog.compid(f), tlog.msgid(f))
        seconds_of = 1e-6 if ts[0] == "time_usec" else 1e-3
        if key in newest and ts[1] <= newest[key]:
            if (newest[key] - ts[1]) * seconds_of > STALE_AFTER:
                backwards.append((key, ts, newest[key]))
            else:
                slightly += 1
        newest[key] = max(ts[1], newest.get(key, -1))
    missing, extra = multiset_diff(frames, got)
    stale = [f for f in missing.elements() if timestamp_of(f) is not None]
    untimed_late = sum(1 for i in da if timestamp_of(frames[i]) is None)
    untimed_missing = sum(1 for f in missing.elements() if timestamp_of(f) is None)
    pos = sum(1 for f in stale if tlog.msgid(f) in (33, 30))
    print(f"\n[7] {n} frames; link A lost {len(da)} (only the late link B carried them); "
          f"stale samples dropped {len(stale)} ({pos} GLOBAL_POSITION_INT/ATTITUDE); frames "
          f"without a timestamp delivered late from B {untimed_late - untimed_missing}; "
          f"timestamps going backwards by more than {STALE_AFTER * 1000:.0f} ms {len(backwards)} "
          f"(by less: {slightly}); duplicates {sum(extra.values())}")
    named = [b for b in backwards if b[0][2] in (33, 30)]  # GLOBAL_POSITION_INT, ATTITUDE
    assert not named, named[:5]
    assert not backwards, backwards[:5]
    assert not extra
    assert untimed_missing == 0, "a frame without a timestamp was dropped"
