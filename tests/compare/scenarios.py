"""The link conditions the comparison runs: each scenario is a set of emulated links
(tests/tools/linkemu.py options, one seed per link), the stream and how long it runs.

Every scenario runs three modes side by side on the same datagrams: one link alone (the first
link), `linkswitch` and `dedup` (both with their defaults). One emulator process carries the
links and tees each to every mode's ground gateway, so a link loses and delays the same
frames in all three modes, whatever the timing."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional


@dataclass
class Link:
    name: str
    label: str            # what the link stands for, for tables and legends
    seed: int
    opts: Dict[str, object]  # linkemu options (both directions)


@dataclass
class Scenario:
    name: str
    title: str
    seconds: float
    links: List[Link]
    note: str = ""
    # Stream-relative outages: {link name: (start s, length s)}, turned into linkemu's
    # --outage (which counts from the emulator's start) when the run starts.
    outages: Dict[str, tuple] = field(default_factory=dict)
    linkswitch: Dict[str, object] = field(default_factory=dict)
    dedup: Dict[str, object] = field(default_factory=dict)
    # "vehicle": the autopilot stream of --stream (a recording, or synthetic); "repeats":
    # 1,000 frames/s of a 256-frame cycle of identical bytes (tests/integration/test_stalls.py);
    # "stamped_1khz": 1,000 ATTITUDE frames/s, each with its own time_boot_ms.
    stream: str = "vehicle"


# The 57600-baud radio: 8N1 leaves 46,080 bit/s of payload; a SiK radio buffers a few KB.
RADIO_57600 = {"rate": 46080, "queue_bytes": 4096}

SCENARIOS: List[Scenario] = [
    Scenario(
        "paper", "The paper's: 1 % loss on each of two links", 120,
        [Link("link1", "1 % loss, 20 ms", 11, {"loss": "1%", "delay": "20ms", "jitter": "2ms"}),
         Link("link2", "1 % loss, 20 ms", 12, {"loss": "1%", "delay": "20ms", "jitter": "2ms"})],
        note="Section 5 of the paper: 1 % loss injected per link (tc there, linkemu here), "
             "UDP, an ArduPilot stream of about 124 frames/s."),
    Scenario(
        "bursty", "Bursty loss (Gilbert-Elliott) on both links", 60,
        [Link("radio1", "GE bursts ~3 %, 20 ms", 21,
              {"ge": "0.003,0.1,0,1", "delay": "20ms", "jitter": "2ms"}),
         Link("radio2", "GE bursts ~3 %, 25 ms", 22,
              {"ge": "0.003,0.1,0,1", "delay": "25ms", "jitter": "2ms"})],
        note="Two radios fading independently: bursts of 10 frames (85 ms) on average, "
             "about 3 % loss each."),
    Scenario(
        "outage", "Link 1 drops out for 15 s", 40,
        [Link("link1", "1 %, 20 ms, down 10-25 s", 31, {"loss": "1%", "delay": "20ms"}),
         Link("link2", "1 %, 20 ms", 32, {"loss": "1%", "delay": "20ms"})],
        outages={"link1": (10.0, 15.0)},
        note="The preferred link is dead from 10 s to 25 s of the stream, then comes back."),
    Scenario(
        "skew", "Latency skew: 5 ms against 300 ms", 60,
        [Link("fast", "1 %, 5 ms", 41, {"loss": "1%", "delay": "5ms"}),
         Link("slow", "1 %, 300 ms", 42, {"loss": "1%", "delay": "300ms"})],
        note="A copy on the slow link arrives 295 ms after the fast one: what the fast link "
             "lost comes late, and late timestamped samples are dropped as stale."),
    Scenario(
        "three", "Three links", 60,
        [Link("radio", "1 %, 15 ms", 51, {"loss": "1%", "delay": "15ms", "jitter": "2ms"}),
         Link("lte", "2 %, 60 ms +-15 ms", 52,
              {"loss": "2%", "delay": "60ms", "jitter": "15ms"}),
         Link("sat", "GE bursts ~5 %, 250 ms", 53,
              {"ge": "0.005,0.1,0.005,1", "delay": "250ms", "jitter": "20ms"})],
        note="A radio, an LTE modem and a satellite link, all lossy."),
    Scenario(
        "radio57600", "A 57600-baud radio beside a fast link", 60,
        [Link("radio", "57600 baud, 1 %, 5 ms", 61,
              {"loss": "1%", "delay": "5ms", **RADIO_57600}),
         Link("lte", "1 %, 50 ms +-15 ms", 62,
              {"loss": "1%", "delay": "50ms", "jitter": "15ms"})],
        note="The stream fills most of the radio's 46 kbit/s of payload: frames queue behind "
             "each other when the autopilot sends in bursts (a full 4 KB queue drops)."),
    Scenario(
        "radio_lte", "A 57600-baud radio beside LTE", 60,
        [Link("radio", "57600 baud, 1 %, 30 ms +-10 ms", 71,
              {"loss": "1%", "delay": "30ms", "jitter": "10ms", **RADIO_57600}),
         Link("lte", "1 %, 60 ms, normal jitter 30 ms, reordering", 72,
              {"loss": "1%", "delay": "60ms", "jitter": "30ms", "jitter_dist": "normal",
               "reorder": True})],
        note="The usual pair: the radio's queue and the modem's jitter (normal, sigma 30 ms, "
             "clipped at 90 ms, so LTE datagrams overtake each other) make the two links' "
             "copies of a frame come in either order, tens of ms apart."),
    Scenario(
        "repeats_1khz", "1,000 frames/s, the same bytes every 256 frames", 30,
        [Link("a", "5 %, 10 ms", 81, {"loss": "5%", "delay": "10ms"}),
         Link("b", "5 %, 310 ms", 82, {"loss": "5%", "delay": "310ms"})],
        stream="repeats",
        note="A 256-frame cycle of HEARTBEAT, SYS_STATUS and VFR_HUD without timestamps, every "
             "4th frame a unique VFR_HUD: the sequence byte wraps every 0.256 s, so byte-"
             "identical frames recur well inside the window, and link b is 300 ms (more than "
             "a cycle) behind link a. Only identity can tell a repeat from a copy."),
]

BY_NAME = {s.name: s for s in SCENARIOS}

MODES = ("single", "linkswitch", "dedup")
MODE_TITLES = {"single": "one link alone", "linkswitch": "linkswitch", "dedup": "dedup"}


def filters_for(mode: str, sc: Scenario) -> List[dict]:
    """The ground gateway's filter chain for a mode."""
    names = [l.name for l in sc.links]
    if mode == "linkswitch":
        return [{"plugin": "linkswitch", "bonds": ["vehicle"], "priority": names,
                 **sc.linkswitch}]
    if mode == "dedup":
        return [{"plugin": "dedup", "bonds": ["vehicle"], **sc.dedup}]
    return []


def links_for(mode: str, sc: Scenario) -> List[Link]:
    return sc.links[:1] if mode == "single" else list(sc.links)


def modes(sc: Scenario) -> Dict[str, tuple]:
    """{mode: (names of the links its ground gateway gets, its filters)}, as lab.run takes."""
    return {m: ([l.name for l in links_for(m, sc)], filters_for(m, sc)) for m in MODES}


def get(name: str) -> Optional[Scenario]:
    return BY_NAME.get(name)
