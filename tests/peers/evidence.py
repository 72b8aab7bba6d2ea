"""What crossed the bond, from the records alone: the two gateways' flight logs (what each
end sent, what was delivered to it) and the emulator's records (every datagram each link
received, and which of them it lost). Nothing is judged by how long anything took: times
give order only, within one gateway's log (which answer came before which retry), and
across the two logs (stamped from the same clock) only where the order is beyond doubt: a
frame is delivered a link's delay, 10 ms at least, after it was sent, and a transfer MAVSDK
gave up on ended seconds before the ground station began it again.

Two questions are answered:

1. Delivery, per direction: each frame an end sent is matched to the datagram index it had
   on every link, from the emulator's record of every datagram each link received (its
   bytes): the gateway sends every frame of an end on every link of the bond, in the order
   its log holds them, one frame per datagram, and between them the link's own count
   markers (mavbond.yaml(5), LINK ACCOUNTING), which it writes itself, never routes, and
   which are in no flight log. With the markers taken out, each link's datagrams must be
   the log's frames, byte for byte, in its order; so the frames lost on every link are
   known. Then: duplicates delivered (a frame delivered more often than it was sent), frames
   lost although some link brought them, frames lost on every link.

2. Retries, per protocol: a retry is a request sent again (the same item asked for twice).
   Each retry is judged by the attempt before it:
     lost     that attempt, or every answer to it, was lost on every link;
     late     it was answered, but that attempt or an answer to it was lost on the faster
              link (the emulator's record), so it came by the slower one, 300 ms later;
     (a retry that left before any answer to that attempt came back is judged as that
              attempt was: both come from the same earlier loss; so too when both reached
              the responder before it answered, and its answers may be to either)
     unexplained  otherwise: every frame of that attempt came the fast way, yet the
              requester asked again; or the responder never answered a request it got. The
              bond caused it (a duplicate set a protocol back, an answer held up), or a peer
              misbehaved.
   Over one clean link nothing is lost, so any retry there is unexplained."""
from __future__ import annotations

import bisect
import struct
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import tlog  # noqa: E402
from pymavlink.dialects.v20 import all as mav2  # noqa: E402

# FTP opcodes (MAVLink FTP: https://mavlink.io/en/services/ftp.html)
FTP_OPEN_RO, FTP_READ_FILE, FTP_BURST_READ, FTP_ACK, FTP_NAK = 4, 5, 15, 128, 129
ARM, TAKEOFF = 400, 22


@dataclass
class Frame:
    t: float            # when its gateway logged it (s, the machine's clock)
    raw: bytes
    msg: object         # pymavlink message
    src: Tuple[int, int]
    lost: bool = False  # sent by an end, never delivered to the other (filled in later)
    delivered_at: Optional[float] = None  # the other gateway's log time of its delivery
    dropped_on: frozenset = frozenset()   # the links that did not carry it


def read_log(directory: Path) -> List[Tuple[float, bytes]]:
    out = []
    for path in sorted(directory.glob("*.tlog")):
        for ts, raw in tlog.iter_frames(path, raw=False):
            out.append((ts / 1e6, raw))
    return out


def decode(raw: bytes):
    m = mav2.MAVLink(None)
    m.robust_parsing = False
    return m.decode(bytearray(raw))


def frames_of(log: List[Tuple[float, bytes]], src: Tuple[int, int]) -> List[Frame]:
    return [Frame(t, raw, decode(raw), src) for t, raw in log
            if (tlog.sysid(raw), tlog.compid(raw)) == src]


def link_marker(raw: bytes, link: str) -> Optional[int]:
    """The count a datagram carries when it is link `link`'s own count marker (named
    mbw:LINK or mbs:LINK, LINK the first 6 characters of the endpoint's name: both gateways
    name the bond's links alike), None for anything else."""
    m = tlog.count_marker(raw)
    if m is None:
        return None
    name = (tlog.payload(raw) + bytes(18))[8:18].rstrip(b"\0")
    return m[0] if name[4:] == link[:6].encode() else None


def content(raw: bytes) -> tuple:
    """A frame without its sequence byte (what a renumbering gateway leaves alone)."""
    return (tlog.sysid(raw), tlog.compid(raw), tlog.msgid(raw), tlog.payload(raw))


@dataclass
class Direction:
    """One end's frames across the bond: sent (in the order its gateway sent them on the
    links), delivered to the other end, and what the links dropped."""
    name: str
    sent: List[Frame]
    delivered: List[Frame]
    dropped: Dict[str, set]          # link -> datagram indices it dropped
    datagrams: Dict[str, List[bytes]]  # link -> every datagram it received, in index order
    counted: Dict[str, int]          # link -> datagrams its counters say it received
    renumbered: bool = False
    duplicates: int = 0
    lost_everywhere: int = 0         # sent, dropped by every link
    lost_by_bond: List[int] = field(default_factory=list)  # indices some link brought, lost
    lost_unhurt: List[int] = field(default_factory=list)   # indices every link brought, lost
    missing: int = 0                 # sent and never delivered
    index_of: Dict[str, List[int]] = field(default_factory=dict)  # link -> frame -> datagram

    def key(self, f: Frame):
        return content(f.raw) if self.renumbered else f.raw

    def _index(self, link: str, datagrams: List[bytes]) -> List[int]:
        """The datagram index of each frame sent on `link`: its datagrams are the frames of
        the sending gateway's log, in order, one each, and the link's own count markers
        (each carrying the number of datagrams written on the link before it: its own
        index, so the record is the whole of what the gateway wrote on the link)."""
        assert len(datagrams) == self.counted[link], (
            f"{self.name}: the emulator's record of link {link} holds {len(datagrams)} "
            f"datagrams, its counters {self.counted[link]}")
        index, markers = [], 0
        for i, raw in enumerate(datagrams):
            count = link_marker(raw, link)
            if count is not None:
                assert count == i, (f"{self.name}: link {link}'s count marker at datagram {i} "
                                    f"carries {count}")
                markers += 1
                continue
            k = len(index)
            assert k < len(self.sent) and raw == self.sent[k].raw, (
                f"{self.name}: link {link}'s datagram {i} (its frame {k}, after {markers} "
                f"count markers) is not frame {k} of the gateway's log, of "
                f"{len(self.sent)}: {raw.hex()} for "
                f"{self.sent[k].raw.hex() if k < len(self.sent) else 'none'}")
            index.append(i)
        assert len(index) == len(self.sent), (
            f"{self.name}: link {link} carried {len(index)} frames (and {markers} count "
            f"markers), the gateway's log holds {len(self.sent)} frames to send")
        return index

    def frame_at(self, link: str, datagram: int) -> Optional[int]:
        """The frame (its index in `sent`) that was datagram `datagram` of `link`, None for
        a count marker."""
        index = self.index_of[link]
        k = bisect.bisect_left(index, datagram)
        return k if k < len(index) and index[k] == datagram else None

    def account(self) -> "Direction":
        for link, datagrams in self.datagrams.items():
            self.index_of[link] = self._index(link, datagrams)
        for f, *at in zip(self.sent, *self.index_of.values()):
            f.dropped_on = frozenset(l for l, i in zip(self.index_of, at)
                                     if i in self.dropped[l])
        everywhere = {i for i, f in enumerate(self.sent)
                      if f.dropped_on == frozenset(self.dropped)}
        self.lost_everywhere = len(everywhere)
        # Match each delivered frame to the frame sent that it is. Identical bytes recur (a
        # source's sequence byte wraps every 256 frames; a battery report may not change), so
        # among the sent frames with its bytes it is the newest one sent before it was
        # delivered (the logs share the machine's clock; the links delay every frame by 10 ms
        # at least), unless that one was already delivered: then an older one that the fast
        # link lost, so that it came the slow way, late; else it is a duplicate.
        instances: Dict[object, List[int]] = defaultdict(list)
        for i, f in enumerate(self.sent):
            instances[self.key(f)].append(i)
        for f in self.delivered:
            cands = [i for i in instances.get(self.key(f), ()) if self.sent[i].t < f.t]
            chosen = None
            if cands and self.sent[cands[-1]].delivered_at is None:
                chosen = cands[-1]
            else:
                late = [i for i in cands if self.sent[i].delivered_at is None
                        and self.sent[i].dropped_on and f.t - self.sent[i].t < 1.0]
                chosen = late[-1] if late else None
            if chosen is None:
                self.duplicates += 1
            else:
                self.sent[chosen].delivered_at = f.t
        for i, f in enumerate(self.sent):
            if f.delivered_at is None:
                f.lost = True
                self.missing += 1
                if i not in everywhere:
                    self.lost_by_bond.append(i)
                if not f.dropped_on:
                    self.lost_unhurt.append(i)
        return self

    def by_type(self) -> Dict[str, Tuple[int, int]]:
        """message name -> (sent, delivered)."""
        out: Dict[str, List[int]] = defaultdict(lambda: [0, 0])
        for f in self.sent:
            out[f.msg.get_type()][0] += 1
            out[f.msg.get_type()][1] += f.delivered_at is not None
        return {k: (a, b) for k, (a, b) in out.items()}


# --- retries ---------------------------------------------------------------------------------

@dataclass
class Exchange:
    """One protocol's request/answer pairs for one requester."""
    name: str
    requester: List[Frame]     # every frame the requester sent (its gateway's log order)
    responder: List[Frame]     # every frame the responder sent
    request_key: Callable[[object], Optional[object]]   # msg -> item key, None: not a request
    answer_key: Callable[[object], Optional[object]]    # msg -> item key, None: not an answer
    first_is_retry: Callable[[object], bool] = lambda k: False
    # for items first asked for by another request (a parameter read after the list, a piece
    # of a file after the burst that should have brought it): (key, first request of that
    # key) -> the request whose answers count as the first attempt's
    implied_by: Optional[Callable[[object, Frame], Optional[Frame]]] = None


@dataclass
class RetryCount:
    retries: int = 0
    lost: int = 0
    late: int = 0
    unexplained: List[str] = field(default_factory=list)
    late_cases: List[str] = field(default_factory=list)

    def add(self, other: "RetryCount") -> None:
        self.retries += other.retries
        self.lost += other.lost
        self.late += other.late
        self.unexplained += other.unexplained
        self.late_cases += other.late_cases

    def as_dict(self) -> dict:
        return {"retries": self.retries, "lost": self.lost, "late": self.late,
                "unexplained": len(self.unexplained)}


def judge(ex: Exchange, fast: str = "fast") -> RetryCount:
    """Every retry of `ex` judged by the attempt before it (see the module's docstring);
    `fast`: the link whose loss makes a frame come the slow way."""
    attempts: Dict[object, List[Frame]] = defaultdict(list)
    for f in ex.requester:
        k = ex.request_key(f.msg)
        if k is not None:
            attempts[k].append(f)
    answers: Dict[object, List[Frame]] = defaultdict(list)
    for f in ex.responder:
        k = ex.answer_key(f.msg)
        if k is not None:
            answers[k].append(f)
    out = RetryCount()
    for key, tries in attempts.items():
        seq = list(tries)
        if ex.implied_by is not None:
            first = ex.implied_by(key, seq[0])
            if first is not None:
                seq = [first] + seq
        verdicts: List[str] = ["first"]
        for j in range(1, len(seq)):
            verdict, why = _verdict(ex, key, seq, j, answers[key], verdicts, fast)
            verdicts.append(verdict)
            out.retries += 1
            if verdict == "lost":
                out.lost += 1
            elif verdict == "late":
                out.late += 1
                out.late_cases.append(why)
            else:
                out.unexplained.append(why)
    return out


def _verdict(ex: Exchange, key, seq: List[Frame], j: int, answers: List[Frame],
             verdicts: List[str], fast: str) -> Tuple[str, str]:
    """lost, late or unexplained, with why, for attempt j judged by attempt j - 1."""
    prev, retry = seq[j - 1], seq[j]
    where = f"{ex.name} {key}"
    if prev.lost:
        return "lost", where
    if fast in prev.dropped_on:
        return "late", f"{where}: the request of {prev.t:.3f} was lost on {fast}"
    # The answers to `prev`: those the responder sent after it had `prev` and before it had
    # a later attempt (all later ones if none came after). Times of the responder's log.
    lo = prev.delivered_at
    hi = min((a.delivered_at for a in seq[j:] if a.delivered_at is not None
              and a.delivered_at > lo), default=float("inf"))
    mine = [a for a in answers if lo <= a.t < hi]
    if not mine:
        # The responder may have had the retry too before it answered: MAVSDK asks again
        # both on a timeout and on a repeated answer, so two requests can leave together and
        # arrive together. When the retry is the next attempt the responder had, its answers
        # from `prev` on until the attempt after the retry are to either; if none of them
        # came back before the retry left, it crossed the answer to `prev` (below).
        arrived = sorted(a.delivered_at for a in seq[j:] if a.delivered_at is not None
                         and a.delivered_at > lo)
        if j >= 2 and arrived and arrived[0] == retry.delivered_at:
            until = arrived[1] if len(arrived) > 1 else float("inf")
            either = [a for a in answers if lo <= a.t < until]
            if either and all(a.delivered_at is None or a.delivered_at > retry.t
                              for a in either):
                return verdicts[j - 1], (f"{where}: crossed the answer to the request of "
                                         f"{prev.t:.3f}, both at the responder before it "
                                         f"answered")
        return "unexplained", (f"{where}: the request sent at {prev.t:.3f} reached the "
                               f"responder, which did not answer it")
    got = [a for a in mine if not a.lost]
    if not got:
        return "lost", where
    if any(fast in a.dropped_on for a in mine):
        return "late", (f"{where}: an answer to the request of {prev.t:.3f} was lost on "
                        f"{fast}")
    first_back = min(a.delivered_at for a in got)
    if first_back > retry.t and j >= 2:
        # The retry left before any answer to `prev` came back (the requester's gateway's
        # log): `prev` did not cause it; it is what `prev` was, a consequence of the same
        # earlier loss (MAVSDK asks again both on a timeout and on a repeated answer).
        return verdicts[j - 1], f"{where}: crossed the answer to the request of {prev.t:.3f}"
    return "unexplained", (f"{where}: asked again at {retry.t:.3f} although the request of "
                           f"{prev.t:.3f} and its answer came the fast way (answered at "
                           f"{first_back:.3f}, the requester's gateway's log)")


def ftp_fields(msg) -> Tuple[int, int, int, int, int]:
    """(seq_number, opcode, size, req_opcode, offset) of a FILE_TRANSFER_PROTOCOL."""
    p = bytes(msg.payload)
    seq, _session, opcode, size, req_opcode, _burst, _pad, offset = struct.unpack_from(
        "<HBBBBBBI", p, 0)
    return seq, opcode, size, req_opcode, offset


def _ftp(frames: List[Frame]) -> List[Tuple[Frame, Tuple[int, int, int, int, int]]]:
    return [(f, ftp_fields(f.msg)) for f in frames if f.msg.get_type() == "FILE_TRANSFER_PROTOCOL"]


def ftp_file_size(vehicle_sent: List[Frame]) -> Optional[int]:
    """The size the server gave in its answer to the open (the first 4 bytes of its data)."""
    for f, (_seq, opcode, size, req, _off) in _ftp(vehicle_sent):
        if opcode == FTP_ACK and req == FTP_OPEN_RO and size >= 4:
            return struct.unpack_from("<I", bytes(f.msg.payload), 12)[0]
    return None


# Each transfer's frames, by sender ("G": the ground station, "V": the vehicle).
TRANSFER_FRAMES = {
    "params": {"G": ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ"), "V": ("PARAM_VALUE",)},
    "mission_upload": {"G": ("MISSION_COUNT", "MISSION_ITEM_INT"),
                       "V": ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")},
    "mission_download": {"G": ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT",
                               "MISSION_REQUEST", "MISSION_ACK"),
                         "V": ("MISSION_COUNT", "MISSION_ITEM_INT")},
    "ftp": {"G": ("FILE_TRANSFER_PROTOCOL",), "V": ("FILE_TRANSFER_PROTOCOL",)},
}


def protocols(gcs_sent: List[Frame], vehicle_sent: List[Frame], fast: str = "fast",
              attempts: Optional[Dict[str, List[dict]]] = None) -> Dict[str, RetryCount]:
    """Retries per protocol, each judged (see judge()). Requests the GCS makes on its own
    schedule (the vehicle's version, home position, message intervals: COMMAND_LONGs other
    than arm and takeoff) are no transfer's and are left out.

    attempts: per transfer, the ground station's attempts ({"t": wall-clock start, "ok"}) when
    it had to start one again. A transfer started again is one retry, explained when a frame
    of the failed attempt was lost on every link; the retries within a transfer are judged
    in its last attempt (the logs share the clock the attempts' starts were read from, and a
    failed attempt ended with MAVSDK's timeouts, seconds before the next began)."""
    attempts = attempts or {}
    out = _protocols(gcs_sent, vehicle_sent, fast, attempts)
    for name, tries in attempts.items():
        kinds = TRANSFER_FRAMES[name]
        for i, a in enumerate(tries[:-1]):
            lo, hi = a["t"], tries[i + 1]["t"]
            frames = [f for f in gcs_sent if f.msg.get_type() in kinds["G"] and lo <= f.t < hi]
            frames += [f for f in vehicle_sent
                       if f.msg.get_type() in kinds["V"] and lo <= f.t < hi]
            out[name].retries += 1
            if any(f.lost for f in frames):
                out[name].lost += 1
            else:
                out[name].unexplained.append(
                    f"{name}: attempt {i + 1} failed ({a.get('why')}) with none of its "
                    f"{len(frames)} frames lost")
    return out


def _protocols(G: List[Frame], V: List[Frame], fast: str,
               attempts: Dict[str, List[dict]]) -> Dict[str, RetryCount]:
    def last_attempt(name: str, frames: List[Frame]) -> List[Frame]:
        tries = attempts.get(name)
        if not tries:
            return frames
        since = tries[-1]["t"]
        return [f for f in frames if f.t >= since]

    def mission(m) -> bool:
        return getattr(m, "mission_type", 0) == 0

    def is_request(m) -> bool:
        return m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and mission(m)

    def is_item(m) -> bool:
        return m.get_type() == "MISSION_ITEM_INT" and mission(m)

    out: Dict[str, RetryCount] = {}

    # Parameters: the list, then single reads of what did not come (the first read of an
    # index is the retry of the list's answer for that index).
    G0, V0 = G, V
    G, V = last_attempt("params", G0), last_attempt("params", V0)
    lists = [f for f in G if f.msg.get_type() == "PARAM_REQUEST_LIST"]
    params = judge(Exchange(
        "PARAM_REQUEST_LIST", G, V,
        lambda m: "list" if m.get_type() == "PARAM_REQUEST_LIST" else None,
        lambda m: "list" if m.get_type() == "PARAM_VALUE" else None), fast)
    params.add(judge(Exchange(
        "PARAM_REQUEST_READ", G, V,
        lambda m: param_key(m) if m.get_type() == "PARAM_REQUEST_READ" else None,
        lambda m: param_key(m) if m.get_type() == "PARAM_VALUE" else None,
        implied_by=lambda _k, first: next((l for l in reversed(lists) if l.t < first.t),
                                          None)), fast))
    out["params"] = params

    # Mission upload: the GCS sends the count (answered by the vehicle's first request), the
    # vehicle asks for each item.
    G, V = last_attempt("mission_upload", G0), last_attempt("mission_upload", V0)
    up = judge(Exchange(
        "MISSION_COUNT", G, V,
        lambda m: "count" if m.get_type() == "MISSION_COUNT" and mission(m) else None,
        lambda m: "count" if is_request(m) or (m.get_type() == "MISSION_ACK" and mission(m))
        else None), fast)
    up.add(judge(Exchange("MISSION_REQUEST_INT (upload)", V, G,
                          lambda m: m.seq if is_request(m) else None,
                          lambda m: m.seq if is_item(m) else None), fast))
    out["mission_upload"] = up

    # Mission download: the GCS asks for the list, then for each item.
    G, V = last_attempt("mission_download", G0), last_attempt("mission_download", V0)
    down = judge(Exchange(
        "MISSION_REQUEST_LIST", G, V,
        lambda m: "list" if m.get_type() == "MISSION_REQUEST_LIST" and mission(m) else None,
        lambda m: "list" if m.get_type() == "MISSION_COUNT" and mission(m) else None), fast)
    down.add(judge(Exchange("MISSION_REQUEST_INT (download)", G, V,
                            lambda m: m.seq if is_request(m) else None,
                            lambda m: m.seq if is_item(m) else None), fast))
    out["mission_download"] = down

    # Arm and take off: each command until its ack.
    G, V = G0, V0
    out["command"] = judge(Exchange(
        "COMMAND_LONG", G, V,
        lambda m: m.command if m.get_type() == "COMMAND_LONG" and m.command in (ARM, TAKEOFF)
        else None,
        lambda m: m.command if m.get_type() == "COMMAND_ACK" and m.command in (ARM, TAKEOFF)
        else None), fast)

    # FTP. A request sent again unchanged (same FTP sequence number; the server answers
    # request n with n + 1). And a piece of the file asked for again (below). The read MAVSDK
    # makes at the end of the file (offset = size, answered by a NAK "end of file") happens
    # over a clean link too: it is the protocol's, not a retry.
    G, V = last_attempt("ftp", G0), last_attempt("ftp", V0)
    ftp_g, ftp_v = _ftp(G), _ftp(V)
    size = ftp_file_size(V)
    ftp = judge(Exchange("FTP request", [f for f, _ in ftp_g], [f for f, _ in ftp_v],
                         lambda m: ftp_fields(m)[0],
                         lambda m: (ftp_fields(m)[0] - 1) & 0xFFFF), fast)
    # A piece is asked for again by a read of it, or by a burst that starts at it (MAVSDK
    # does both); its first attempt is the burst that sent it and whose chunk the GCS did not
    # get. A burst that goes on where the previous one ended asks for no piece twice.
    bursts = [f for f, fl in ftp_g if fl[1] == FTP_BURST_READ and f.delivered_at is not None]
    chunks = [(f, fl[4]) for f, fl in ftp_v if fl[1] == FTP_ACK and fl[3] == FTP_BURST_READ]

    def burst_for(offset, first):
        # Times of the vehicle's gateway's log (a request's delivery, a chunk's sending); for
        # a request lost on the way, when the GCS's gateway sent it (the chunk it replaces
        # left the vehicle before the GCS could miss it: a link's delay, 10 ms, earlier).
        until = first.delivered_at if first.delivered_at is not None else first.t
        sent = [c for c, o in chunks if o == offset and c.t < until]
        if not sent:
            return None
        return next((b for b in reversed(bursts) if b.delivered_at <= sent[-1].t), None)

    # Each request once: one sent again unchanged is the retry judged just above.
    firsts, seen = [], set()
    for f, fl in ftp_g:
        if fl[0] not in seen:
            seen.add(fl[0])
            firsts.append(f)

    def piece(m):
        _seq, opcode, _size, _req, offset = ftp_fields(m)
        if opcode == FTP_READ_FILE and (size is None or offset < size):
            return offset
        if opcode == FTP_BURST_READ:
            return offset
        return None

    ftp.add(judge(Exchange(
        "FTP piece asked for again", firsts, [f for f, _ in ftp_v], piece,
        lambda m: ftp_fields(m)[4] if ftp_fields(m)[1] == FTP_ACK and ftp_fields(m)[3] in (
            FTP_BURST_READ, FTP_READ_FILE) else None,
        implied_by=burst_for), fast))
    out["ftp"] = ftp
    return out


def param_key(m):
    """A parameter by index, or by name when a read asks by name (index -1)."""
    idx = m.param_index
    if m.get_type() == "PARAM_REQUEST_READ" and idx in (-1, 65535):
        return m.param_id
    return idx


def ftp_naks(vehicle_sent: List[Frame], gcs_sent: List[Frame]) -> Tuple[int, int]:
    """(NAKs, of which answers to a read at the end of the file)."""
    size = ftp_file_size(vehicle_sent)
    eof_reads = {fl[0] for _, fl in _ftp(gcs_sent)
                 if fl[1] == FTP_READ_FILE and size is not None and fl[4] >= size}
    naks = [fl for _, fl in _ftp(vehicle_sent) if fl[1] == FTP_NAK]
    return len(naks), sum(1 for fl in naks if (fl[0] - 1) & 0xFFFF in eof_reads)


def repeats(vehicle_sent: List[Frame], gcs_sent: List[Frame]) -> Dict[str, int]:
    """The figures the issue names, counted from what each end sent: PARAM_VALUEs sent more
    than once for one index, MISSION_REQUESTs for an item already asked for (upload: the
    vehicle's; download: the GCS's), FTP requests sent again, reads of missed pieces, NAKs."""
    pv = Counter(f.msg.param_index for f in vehicle_sent if f.msg.get_type() == "PARAM_VALUE")
    req_v = Counter(f.msg.seq for f in vehicle_sent
                    if f.msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"))
    req_g = Counter(f.msg.seq for f in gcs_sent
                    if f.msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"))
    ftp_g = [fl for _, fl in _ftp(gcs_sent)]
    size = ftp_file_size(vehicle_sent)
    naks, eof_naks = ftp_naks(vehicle_sent, gcs_sent)
    return {
        "repeated_param_values": sum(n - 1 for n in pv.values()),
        "param_reads": sum(1 for f in gcs_sent if f.msg.get_type() == "PARAM_REQUEST_READ"),
        "duplicate_mission_requests_upload": sum(n - 1 for n in req_v.values()),
        "duplicate_mission_requests_download": sum(n - 1 for n in req_g.values()),
        "command_retransmissions": sum(1 for f in gcs_sent if f.msg.get_type() == "COMMAND_LONG"
                                       and f.msg.command in (ARM, TAKEOFF)
                                       and f.msg.confirmation > 0),
        "ftp_requests": len(ftp_g),
        "ftp_resent": sum(n - 1 for n in Counter(fl[0] for fl in ftp_g).values()),
        "ftp_rereads": sum(1 for fl in ftp_g if fl[1] == FTP_READ_FILE
                           and (size is None or fl[4] < size)),
        "ftp_naks": naks - eof_naks,
        "ftp_eof_naks": eof_naks,
    }
