"""The truth of a SITL rig run, from the link models' records, and what the operator saw, from
MAVProxy's telemetry log and console and the gateways' own tools.

Frames are followed by content, not by bytes alone: (sysid, compid, msgid, payload) without a
signature (a signed copy is the same frame) and without the sequence number (the bond numbers
what it sends, routing/egress_numbering.h, but with one number on every copy of a frame). The
copies of a frame on the two links are known by that number; a frame handed to the links is
SITL's frame with that content sent last before a link took its first copy (the air gateway
sends a sample at once or, held back by a budget, not at all once a newer one came: a thinned
frame never leaves), so each of SITL's frames is known to have been carried by the radio, by
LTE, by both or by neither, and whether the air gateway handed it to any link at all. Nothing
is judged by how long anything took; times order events and say what was in flight."""
from __future__ import annotations

import json
import re
import sys
from bisect import bisect_right
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Tuple

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "tools"))
import tlog  # noqa: E402
from pymavlink.dialects.v20 import all as mav2  # noqa: E402

VEHICLE = (1, 1)                 # ArduCopter SITL
LINKS = ("radio", "lte")
DIRECTIONS = ("up", "down")      # up: vehicle -> ground
SLACK = 0.05                     # s: clocks of different processes, read at different moments
SAME_FRAME = 5.0                 # s: copies of one frame reach the two links this close at most
                                 # (the radio lagged LTE 4.8 s in a parameter download)


def identity(frame: bytes) -> tuple:
    """(seq, sysid, compid, msgid, payload): the frame without its signature."""
    return (tlog.seq(frame), tlog.sysid(frame), tlog.compid(frame), tlog.msgid(frame),
            tlog.payload(frame))


def content(frame: bytes) -> tuple:
    """The identity without the sequence byte (what a renumbering gateway leaves alone)."""
    return identity(frame)[1:]


def name_of(msgid: int) -> str:
    cls = mav2.mavlink_map.get(msgid)
    return cls.msgname if cls is not None else str(msgid)


def decode(frame: bytes):
    m = mav2.MAVLink(None)
    m.robust_parsing = True
    try:
        return m.decode(bytearray(frame))
    except Exception:
        return None


# --- the records -------------------------------------------------------------------------------

@dataclass
class Hop:
    """One frame handed to one link in one direction, and what the link did with it."""
    link: str
    direction: str
    t_in: float
    decided: float                 # when its fate was sealed: delivered, or dropped
    fate: str                      # carried, overflow, cut (radio); loss, outage (lte); ...
    raw: bytes

    @property
    def carried(self) -> bool:
        return self.fate == "carried"


@dataclass
class Sent:
    """One frame SITL sent (the wire's record) and its hops."""
    i: int
    t: float
    raw: bytes
    hops: Dict[str, Hop] = field(default_factory=dict)

    @property
    def handed(self) -> bool:
        return bool(self.hops)

    @property
    def carried(self) -> bool:
        return any(h.carried for h in self.hops.values())

    @property
    def arrived(self) -> Optional[float]:
        """When its first copy left a link (reached the ground gateway)."""
        ts = [h.decided for h in self.hops.values() if h.carried]
        return min(ts) if ts else None


def _jsonl(path: Path) -> List[dict]:
    return [json.loads(l) for l in path.read_text().splitlines() if l.strip()]


class Records:
    """Everything the links recorded in one run (rig directory's links/)."""

    def __init__(self, links_dir: Path, clock: Tuple[float, float]):
        self.mono0, self.wall0 = clock
        self.wire: Dict[str, List[Tuple[float, bytes]]] = {"up": [], "down": []}
        for r in _jsonl(links_dir / "wire.jsonl"):
            self.wire[r["dir"]].append((r["t"], bytes.fromhex(r["hex"])))
        self.hops: Dict[Tuple[str, str], List[Hop]] = defaultdict(list)
        self.reports: List[dict] = []
        for r in _jsonl(links_dir / "radio.jsonl"):
            if "report" in r:
                self.reports.append(r)
                continue
            decided = r["t_in"] if r["fate"] == "overflow" else r["t_air"]
            self.hops[("radio", r["dir"])].append(
                Hop("radio", r["dir"], r["t_in"], decided, r["fate"], bytes.fromhex(r["hex"])))
        for r in _jsonl(links_dir / "lte.jsonl"):
            data = bytes.fromhex(r["hex"])
            decided = r["t_out"] if r["fate"] == "carried" else r["t_in"]
            if decided is None:        # still in flight when the model stopped
                decided = float("inf")
            for f in _frames(data):
                self.hops[("lte", r["dir"])].append(
                    Hop("lte", r["dir"], r["t_in"], decided, r["fate"], f))
        for hops in self.hops.values():
            hops.sort(key=lambda h: h.t_in)
        self.sent = [Sent(i, t, f) for i, (t, f) in enumerate(
            (t, f) for t, f in self.wire["up"] if (tlog.sysid(f), tlog.compid(f)) == VEHICLE)]
        self.unplaced, self.unmatched = self._attribute()

    def mono(self, wall: float) -> float:
        """A time of time.time() (MAVProxy's log) on the records' clock."""
        return wall - self.wall0 + self.mono0

    def _attribute(self) -> Tuple[Dict[str, int], Dict[str, int]]:
        """Gives each of SITL's frames its hops (up): the copies of one frame (copies()) go to
        the frame of their content SITL sent last before the first of them was taken, and not
        given that link's hop yet. No slack: the models read one clock, and the wire records a
        frame before it forwards it, so no copy is taken before its frame was sent. Returns,
        per link, the hops SITL never sent (more of a content on the link by a time than SITL
        had sent by then: none when the records are whole), and those left without a frame
        (copies of a constant sample in a run of them, paired with none, whose frames went to
        other hops: a rare ambiguity of the matching, not of the records)."""
        by_id: Dict[tuple, List[int]] = defaultdict(list)
        for s in self.sent:
            by_id[content(s.raw)].append(s.i)
        times = {k: [self.sent[i].t for i in v] for k, v in by_id.items()}
        ours = [h for link in LINKS for h in self.hops[(link, "up")]
                if (tlog.sysid(h.raw), tlog.compid(h.raw)) == VEHICLE]
        never_sent = {link: 0 for link in LINKS}
        seen: Dict[tuple, int] = Counter()
        for h in sorted(ours, key=lambda h: h.t_in):
            k = content(h.raw)
            seen[(h.link, k)] += 1
            never_sent[h.link] += seen[(h.link, k)] > bisect_right(times.get(k, []), h.t_in)
        unmatched = {link: 0 for link in LINKS}
        for frame in copies(ours):
            k = content(frame[0].raw)
            idx = by_id.get(k, [])
            j = bisect_right(times.get(k, []), frame[0].t_in) - 1
            while j >= 0 and any(h.link in self.sent[idx[j]].hops for h in frame):
                j -= 1
            for h in frame:
                if j < 0:
                    unmatched[h.link] += 1
                else:
                    self.sent[idx[j]].hops[h.link] = h
        return never_sent, unmatched


def copies(hops: Iterable[Hop]) -> List[List[Hop]]:
    """Hops grouped into the frames they carried, in the order of their first copy. The bond
    sends every copy of a frame with one number (routing/egress_numbering.h), so two hops of
    one identity, sequence byte included, on the two links, within SAME_FRAME of each other
    are the copies of one frame, when nothing else is: an identity recurs 256 of its source's
    numbers later (a second and a half of ArduCopter's stream), so where either hop has
    another of that identity on the other link within SAME_FRAME, each is its own. Matched by
    content and time alone, a constant sample (WIND, SYS_STATUS on the ground) that the
    radio's queue held until SITL had sent the next one went to that next one, and the next
    one's radio copy to it."""
    by_id: Dict[tuple, Dict[str, List[Hop]]] = defaultdict(lambda: defaultdict(list))
    for h in hops:
        by_id[identity(h.raw)][h.link].append(h)
    def near(h: Hop, others: List[Hop]) -> List[Hop]:
        return [o for o in others if abs(o.t_in - h.t_in) <= SAME_FRAME]

    frames: List[List[Hop]] = []
    for links in by_id.values():
        if len(links) < 2:
            frames += [[h] for v in links.values() for h in v]
            continue
        xs, ys = links.values()
        paired = set()
        for x in xs:
            c = near(x, ys)
            if len(c) == 1 and len(near(c[0], xs)) == 1:
                frames.append([x, c[0]])
                paired.update((id(x), id(c[0])))
        frames += [[h] for h in xs + ys if id(h) not in paired]
    for f in frames:
        f.sort(key=lambda h: h.t_in)
    frames.sort(key=lambda f: f[0].t_in)
    return frames


def _frames(data: bytes) -> List[bytes]:
    return [r.data for r in tlog.iter_records_bytes(data, raw=True) if r.kind == "frame"]


# --- what the GCS received ---------------------------------------------------------------------

@dataclass
class Delivery:
    t: float          # on the records' clock
    raw: bytes


def gcs_log(tlog_path: Path, records: Records) -> List[Delivery]:
    """MAVProxy's telemetry log: every frame it received (its log leaves out BAD_DATA only),
    in order, on the records' clock."""
    out = []
    for ts, raw in tlog.iter_frames(tlog_path, raw=False):
        out.append(Delivery(records.mono(ts / 1e6), raw))
    return out


@dataclass
class DuplicateCount:
    delivered: int = 0
    matched: int = 0
    duplicates: Counter = field(default_factory=Counter)      # message name -> count
    unknown: Counter = field(default_factory=Counter)         # content SITL never sent
    renumbered: bool = False
    examples: List[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        return sum(self.duplicates.values())


def duplicates(records: Records, deliveries: Iterable[Delivery],
               horizon: float = 10.0) -> DuplicateCount:
    """SITL's frames the GCS received more often than SITL sent them. Each delivery is
    matched to a frame SITL sent with its content, that some link carried to the ground
    gateway before the delivery (and at most `horizon` before), not matched yet; of several,
    the one with the delivery's sequence number when the stream keeps SITL's numbering (else
    the oldest: a greedy matching by time that pairs as many deliveries as can be paired).
    A delivery left without a frame is a duplicate."""
    out = DuplicateCount()
    deliveries = [d for d in deliveries if (tlog.sysid(d.raw), tlog.compid(d.raw)) == VEHICLE]
    by_content: Dict[tuple, List[Sent]] = defaultdict(list)
    for s in records.sent:
        if s.arrived is not None:
            by_content[content(s.raw)].append(s)
    for v in by_content.values():
        v.sort(key=lambda s: s.arrived)
    identities = {identity(s.raw) for s in records.sent}
    same_seq = sum(1 for d in deliveries if identity(d.raw) in identities)
    out.renumbered = bool(deliveries) and same_seq < 0.99 * len(deliveries)
    used: set = set()
    pos: Dict[tuple, int] = defaultdict(int)   # per content: the oldest not expired
    for d in deliveries:
        out.delivered += 1
        k = content(d.raw)
        cands = by_content.get(k)
        if not cands:
            out.unknown[name_of(tlog.msgid(d.raw))] += 1
            continue
        while pos[k] < len(cands) and cands[pos[k]].arrived < d.t - horizon:
            pos[k] += 1
        choice = None
        for s in cands[pos[k]:]:
            if s.arrived > d.t + SLACK:
                break
            if s.i in used:
                continue
            if out.renumbered or identity(s.raw) == identity(d.raw):
                choice = s
                break
        if choice is None:
            out.duplicates[name_of(tlog.msgid(d.raw))] += 1
            if len(out.examples) < 10:
                out.examples.append(f"{name_of(tlog.msgid(d.raw))} seq {tlog.seq(d.raw)} "
                                    f"at {d.t - records.mono0:.3f} s")
        else:
            used.add(choice.i)
            out.matched += 1
    return out


def mavproxy_loss(deliveries: Iterable[Delivery]) -> Dict[tuple, int]:
    """The sequence gaps MAVProxy counts (pymavlink's post_message), per source: every
    source but the SiK radios' (51, 68); a step back counts as the distance forward."""
    last: Dict[tuple, int] = {}
    lost: Counter = Counter()
    for d in deliveries:
        src = (tlog.sysid(d.raw), tlog.compid(d.raw))
        if src == (51, 68):
            continue
        seq = tlog.seq(d.raw)
        if src in last:
            lost[src] += (seq - (last[src] + 1)) % 256
        else:
            lost[src] += 0
        last[src] = seq
    return dict(lost)


def true_gcs_loss(records: Records, deliveries: List[Delivery]) -> Tuple[int, int]:
    """(frames no link carried, frames delivered) of SITL's stream between the first and the
    last of its frames this GCS received: of what the air gateway handed to a link, what no
    link carried."""
    mine = [d for d in deliveries if (tlog.sysid(d.raw), tlog.compid(d.raw)) == VEHICLE]
    if not mine:
        return 0, 0
    a, b = mine[0].t, mine[-1].t
    window = [s for s in records.sent if s.arrived is not None and a - SLACK <= s.arrived <= b]
    if not window:
        return 0, len(mine)
    lo, hi = window[0].i, window[-1].i
    lost = sum(1 for s in records.sent[lo:hi + 1] if s.handed and not s.carried)
    return lost, len(mine)


# --- the links' truth at a moment --------------------------------------------------------------

@dataclass
class LinkTruth:
    handed: int
    lost: int
    in_flight: int

    @property
    def pct(self) -> float:
        return 100.0 * self.lost / self.handed if self.handed else 0.0


def link_truth(records: Records, link: str, direction: str, t: float) -> LinkTruth:
    """Of every frame handed to `link` in `direction` whose fate was sealed by `t`: how many,
    how many it lost; and how many were still on their way at `t`. A frame lost after the
    last count marker that reached the far gateway by `t` is on its way too, for that gateway:
    its loss is told by the next marker (mavbond.yaml(5), LINK ACCOUNTING), and till then it
    is one the link may yet bring."""
    hops = [h for h in records.hops[(link, direction)] if h.t_in <= t]
    told = max((h.t_in for h in hops if h.carried and h.decided <= t and tlog.count_marker(h.raw)),
               default=float("-inf"))
    handed = lost = flight = 0
    for h in hops:
        if h.decided > t or (not h.carried and h.t_in > told):
            flight += 1
            continue
        handed += 1
        lost += not h.carried
    return LinkTruth(handed, lost, flight)


def bond_truth(records: Records, direction: str, t: float) -> LinkTruth:
    """Of the frames handed to at least one link (one frame, however many links it was handed
    to), those no link carried, sealed by `t`. SITL's frames are known by the wire's record
    (their hops attributed); any other frame's copies are the hops of its identity on the
    other link closest in time (within SAME_FRAME). A count marker is no frame of the bond:
    the link's own, written on it alone and never routed (mavbond.yaml(5), LINK ACCOUNTING),
    its loss is the link's."""
    frames: List[List[Hop]] = []
    if direction == "up":
        frames = [list(s.hops.values()) for s in records.sent
                  if s.hops and min(h.t_in for h in s.hops.values()) <= t]
    frames += copies(h for link in LINKS for h in records.hops[(link, direction)]
                     if h.t_in <= t and tlog.count_marker(h.raw) is None
                     and not (direction == "up" and
                              (tlog.sysid(h.raw), tlog.compid(h.raw)) == VEHICLE))
    handed = lost = flight = 0
    for g in frames:
        if any(x.carried and x.decided <= t for x in g):
            handed += 1
        elif all(x.decided <= t for x in g):
            handed += 1
            lost += 1
        else:
            flight += 1
    return LinkTruth(handed, lost, flight)


def in_flight_at(records: Records, t: float, direction: str = "up") -> int:
    """SITL's frames (or the GCS's, down) on a link at `t`: handed, fate not sealed."""
    return sum(1 for link in LINKS for h in records.hops[(link, direction)]
               if h.t_in <= t < h.decided and (direction == "down" or
                                               (tlog.sysid(h.raw), tlog.compid(h.raw)) == VEHICLE))


# --- when the rig stood still ------------------------------------------------------------------

STOOD_STILL = 1.0                # s: SITL's UART, or a link holding frames, silent this long
REPORT_LAG = 3.0                 # s: a far side's report of a silence comes this much after it
                                 # at most (its check, then its report's next turn on LTE)


def _gaps(times: List[float], at_least: float) -> List[Tuple[float, float]]:
    times = sorted(times)
    return [(a, b) for a, b in zip(times, times[1:]) if b - a >= at_least]


def _merged(spans: Iterable[Tuple[float, float]]) -> List[Tuple[float, float]]:
    out: List[Tuple[float, float]] = []
    for a, b in sorted(spans):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


GATEWAY_STALL = re.compile(r"event loop woke (\d+\.\d+) s later than its next timer")


def rig_stalls(records: Records, logs: Iterable[str] = ()) -> List[Tuple[float, float]]:
    """When the rig stood still, by its own records: SITL's UART silent STOOD_STILL s or more
    (on a saturated machine the kernel's tty flush worker gets no CPU and every pty of the rig
    stands still with it, the gateways' radio ports too), a link model that held a frame
    through that long without delivering any, or a gateway that says (its log) it woke that
    much late, held by the kernel. None is a product's choice: the air gateway writes what
    SITL sends, a model delivers what it took, and a gateway held sends nothing."""
    spans = _gaps([t for t, _ in records.wire["up"]], STOOD_STILL)
    for log in logs:
        for line in log.splitlines():
            m = GATEWAY_STALL.search(line)
            if m and float(m.group(1)) >= STOOD_STILL:
                t = records.mono(log_time(line))
                spans.append((t - float(m.group(1)), t))
    for hops in records.hops.values():
        carried = [h for h in hops if h.carried]
        spans += [(a, b) for a, b in _gaps([h.decided for h in carried], STOOD_STILL)
                  if any(h.t_in < a and h.decided >= b for h in carried)]
    return _merged(spans)


def silences(records: Records, link: str, direction: str) -> List[Tuple[float, float]]:
    """Spans in which `link` delivered nothing in `direction` for STOOD_STILL s or more: what
    its receiving gateway heard of it, whatever the cause."""
    return _gaps([h.decided for h in records.hops[(link, direction)] if h.carried], STOOD_STILL)


# The gateways' words for a direction (src/routing/link_events.h): "downlink" is the vehicle's
# frames towards the ground station, "uplink" the other way; a link lost both ways says neither.
EVENT_DIRECTIONS = {"downlink": ("up",), "uplink": ("down",), "": ("up", "down")}


class StallEvents:
    """Which of a run's link changes a gateway logged are the rig's stalls told truly: a link
    lost while it really delivered nothing that way (a silence of STOOD_STILL s or more,
    overlapping a stall of the rig, the event within it or a second after), and its return
    after such a loss. Anything else is the product's."""

    def __init__(self, records: Records, stalls: List[Tuple[float, float]]):
        self.records, self.stalls = records, stalls
        self._silences = {(l, d): [(a, b) for a, b in silences(records, l, d)
                                   if any(s < b and e > a for s, e in stalls)]
                          for l in LINKS for d in DIRECTIONS}

    def silent(self, link: str, direction: str, t: float, reported: bool = False) -> bool:
        """Whether `link` was silent `direction` at `t` (a second after, or REPORT_LAG for
        what the far side reports: its report comes on another link, after its own check)."""
        dirs = EVENT_DIRECTIONS.get(direction, ())
        lag = REPORT_LAG if reported else 1.0
        return bool(dirs) and all(any(a <= t <= b + lag for a, b in self._silences[(link, d)])
                                  for d in dirs)

    def radio_failing(self, t: float) -> bool:
        """Whether a failover at `t` answers what the radio really did: silent either way
        then, over a stall of the rig (the standby acts on a failing radio before a link event
        calls it lost), or dropping frames in the 5 s before (the backlog a stall left
        overflows its buffer once it runs again)."""
        return any(a <= t <= b + 1.0 for d in DIRECTIONS for a, b in self._silences[("radio", d)]) \
            or any(t - 5.0 <= h.decided <= t and not h.carried
                   for d in DIRECTIONS for h in self.records.hops[("radio", d)])

    def split(self, log: str) -> Tuple[List[Tuple[float, str]], List[Tuple[float, str]]]:
        """(the rig's, the product's) of a gateway log's changes, each (time, line)."""
        rig, product = [], []
        lost: Dict[Tuple[str, str], bool] = {}
        for line in logged_changes(log):
            t = self.records.mono(log_time(line))
            ev = logged_event(line)
            if ev is None:                      # a bond's switch: in a stall or 5 s after
                (rig if any(s <= t <= e + 5.0 for s, e in self.stalls) else product).append((t, line))
                continue
            link, direction, what = link_of(ev[0]), ev[1], ev[2]
            key = (link, direction)
            ok = (self.silent(link, direction, t, "as the far side reports" in line)
                  if what == "lost" else lost.get(key, False))
            lost[key] = ok if what == "lost" else False
            (rig if ok else product).append((t, line))
        return rig, product

    @staticmethod
    def told(t: float, line: str, rig_logged: Iterable[List[Tuple[float, str]]]) -> bool:
        """Whether an event a GCS or SITL got at `t` (a console line or a STATUSTEXT) is one
        of `rig_logged` (split()'s first lists) in the 5 s before: the same link and change,
        and the same way unless it tells of the link as a whole (a STATUSTEXT does)."""
        ev = link_event(line)
        return ev is not None and any(
            x is not None and t - 5.0 <= at <= t + SLACK and (x[0], x[2]) == (ev[0], ev[2])
            and ev[1] in ("", x[1])
            for logged in rig_logged for at, l in logged for x in [logged_event(l)])


LOGGED_EVENT = re.compile(r"link event: link (\S+) (?:(downlink|uplink|inbound|outbound) )?(lost|back) ")


def logged_event(line: str) -> Optional[Tuple[str, str, str]]:
    """(endpoint, direction or "", "lost" | "back") of a gateway's logged link event, as
    link_event() gives a shown one; None for any other line."""
    m = LOGGED_EVENT.search(line)
    return (m.group(1), m.group(2) or "", m.group(3)) if m else None


def log_time(line: str) -> float:
    """The time.time() of a gateway's log line ("2026-12-03 08:52:24.930 mavbond: ..."): the
    daemon writes its local time."""
    return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S.%f").timestamp()


# --- what the operator's tools show ------------------------------------------------------------

def endpoint_of(link: str) -> str:
    """The gateways' endpoint name of a link model."""
    return {"radio": "sik", "lte": "lte"}[link]


def link_of(endpoint: str) -> str:
    """The link model of a gateways' endpoint name (the name itself if none)."""
    return next((l for l in LINKS if endpoint_of(l) == endpoint), endpoint)


def status_link_figures(doc: dict, link: str) -> List[Tuple[str, float]]:
    """(entry name, loss %) of every stats entry of an endpoint (a learned peer's entry is
    named endpoint@address: a NAT rebinding makes another)."""
    name = endpoint_of(link)
    out = []
    for f in doc.get("filters", []):
        if f.get("plugin") != "stats":
            continue
        for l in f.get("status", {}).get("links", []):
            if l["name"] == name or l["name"].startswith(name + "@"):
                out.append((l["name"], l.get("loss_pct")))
    return out


def status_bond_loss(doc: dict) -> Optional[float]:
    for f in doc.get("filters", []):
        if f.get("plugin") == "stats":
            for b in f.get("status", {}).get("bonds", []):
                return b.get("delivered_loss_pct")
    return None


def status_standby(doc: dict) -> Optional[str]:
    for b in doc.get("bonds", []):
        if "standby" in b:
            return b["standby"].get("state")
    return None


def status_last_rx_ms(doc: dict, link: str) -> Optional[int]:
    e = next((e for e in doc.get("endpoints", []) if e["name"] == endpoint_of(link)), None)
    return None if e is None else e.get("last_rx_ms_ago")


# A link's row of `mavbondctl watch` (mavbondctl(1)): the active-link mark, then LINK, BOND,
# STATE, LOSS, BY, RX/S, LAST RX.
WATCH_LINE = re.compile(r"^(?P<mark>[* ]) (?P<name>\S+)\s+(?P<bond>\S+)\s+(?P<state>\S+)\s+"
                        r"(?P<loss>\S+)\s+(?P<by>\S+)\s+(?P<rate>\S+)\s+(?P<ago>\S+)$")


def watch_links(text: str) -> Dict[str, Tuple[str, str]]:
    """{link name: (loss column, its whole line)} from `mavbondctl watch`."""
    out = {}
    for line in text.splitlines():
        m = WATCH_LINE.match(line)
        if m and m["name"] != "LINK":
            out[m["name"]] = (m["loss"], line)
    return out


METRIC = re.compile(r"^(\w+)\{([^}]*)\}\s+(\S+)$")


def metrics_samples(text: str, name: str) -> List[Tuple[dict, float]]:
    out = []
    for line in text.splitlines():
        m = METRIC.match(line)
        if m and m.group(1) == name:
            labels = dict(re.findall(r'(\w+)="([^"]*)"', m.group(2)))
            out.append((labels, float(m.group(3))))
    return out


def metrics_link_loss(text: str, link: str) -> List[Tuple[str, float]]:
    name = endpoint_of(link)
    return [(l["link"], 100 * v) for l, v in metrics_samples(text, "mavbond_stats_link_loss_ratio")
            if l["link"] == name or l["link"].startswith(name + "@")]


def metrics_bond_loss(text: str) -> Optional[float]:
    s = metrics_samples(text, "mavbond_stats_bond_delivered_loss_ratio")
    return 100 * s[0][1] if s else None


def metrics_value(text: str, name: str, **labels) -> Optional[float]:
    for l, v in metrics_samples(text, name):
        if all(l.get(k) == v2 for k, v2 in labels.items()):
            return v
    return None


# --- the console -------------------------------------------------------------------------------

# mavbond's STATUSTEXTs (LINK EVENTS in mavbond.yaml(5)): a link as a whole, "mavbond: link sik
# lost (bond vehicle, 1 of 2 up)" or "mavbond: sik lost (vehicle 1/2 up)", one way only "mavbond:
# sik uplink lost (vehicle 1/2 up)"; a bond's switch "mavbond: bond vehicle switched to lte".
LINK_EVENT = re.compile(r"mavbond: (?:link )?(\w+)(?: (downlink|uplink|inbound|outbound))? "
                        r"(lost|back) \(|mavbond: (?:bond )?(\w+) (?:switched to|now on) ")
# A gateway's log line of a change (`link event: ...`): a link lost or back either way, a bond's
# active link switched; not a link heard for the first time or a bond's first choice.
LOGGED_CHANGE = re.compile(r"link event: (?:link \S+ (?:\w+ )?(?:lost|back) |bond \S+: active "
                           r"link now )")


def link_event(line: str) -> Optional[Tuple[str, str, str]]:
    """(link, direction or "", "lost" | "back") of a link event shown, ("bond", name,
    "switched") of a switch; None for any other line."""
    m = LINK_EVENT.search(line)
    if m is None:
        return None
    if m.group(3):
        return (m.group(1), m.group(2) or "", m.group(3))
    return ("bond", m.group(4), "switched")


def link_events_shown(lines: Iterable[Tuple[float, str]]) -> List[Tuple[float, str]]:
    """The link events a console showed: (time, line)."""
    return [(t, l) for t, l in lines if LINK_EVENT.search(l)]


def logged_changes(log: str) -> List[str]:
    """The link events a gateway logged that are changes (its LINK EVENTS lines but a link's
    first frame and a bond's first active link, the start)."""
    return [l for l in log.splitlines() if LOGGED_CHANGE.search(l)]


def statustexts(frames: Iterable[Tuple[float, bytes]]) -> List[Tuple[float, tuple, str]]:
    """(time, source, text) of every STATUSTEXT among frames."""
    out = []
    for t, f in frames:
        if tlog.msgid(f) == 253:
            m = decode(f)
            if m is not None:
                out.append((t, (tlog.sysid(f), tlog.compid(f)), m.text))
    return out
