#!/usr/bin/env python3
"""The link emulator (tests/tools/linkemu.py --group) with one thing added: a link can be cut
and restored when the traffic reaches a given point, not at a given time.

    cutlinks.py --group SPEC.json --cuts CUTS.json --cut-log CUTS-DONE.jsonl

SPEC.json is linkemu's group spec. CUTS.json is a list of steps taken one after the other:

    [{"on": {"link": "fast", "dir": "up", "msgid": 22, "count": 150},
      "do": [["cut", "fast"]]},
     {"on": {"link": "fast", "dir": "up", "msgid": 22, "count": 10},
      "do": [["restore", "fast"], ["cut", "slow"]]}, ...]

A step fires on the `count`-th datagram carrying `msgid` (its first frame's) that arrives on
link `on.link` in direction `on.dir` after the previous step fired (datagrams a cut link
drops still arrive, so they count); with `"total": true` in `on`, counting from the start
instead (if that many came before the previous step fired, on the next one). `cut` drops
everything on a link from the datagram after the one that fires the step, in both
directions, recorded in the drop logs with reason "outage" like linkemu's timed outages;
`restore` ends a cut from the datagram that fires the step, which passes (see Cutter for how
this holds across links). So where a cut falls in a transfer depends only on the protocol's
progress, never on the machine's timing. Each step taken is one JSON line in the cut log
(written as it is taken): the step, the counting link's datagram `index` in that direction,
its `frame` (its index among the datagrams of that link and direction that are no count
marker: see Cutter), and the time (s since the group started).

Everything else (banner, signals, counters on stdout, drop and send logs) is linkemu's, so
tests/integration/bonding_helpers.EmuGroup drives it unchanged."""
from __future__ import annotations

import argparse
import json
import math
import signal
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import linkemu  # noqa: E402
import tlog  # noqa: E402


def msgid_of(data: bytes) -> int:
    if len(data) >= 10 and data[0] == 0xFD:
        return data[7] | data[8] << 8 | data[9] << 16
    if len(data) >= 6 and data[0] == 0xFE:
        return data[5]
    return -1


class Cutter:
    """Takes the steps. The links of a group carry the same frames in the same order in each
    direction (one sender fans every frame out to all of them), and between them each link's
    own count markers (mavbond.yaml(5), LINK ACCOUNTING: every bond member writes its own,
    about once a second, wherever its timer falls), so a datagram's index is not the same
    frame's on every link: its frame position is, the number of datagrams before it on that
    link and direction that are no count marker (a marker's: the frames before it). A step's
    cuts and restores take effect at a frame position of the step's direction, not at an
    instant: link B cut "from now" while its socket has not been read as far as link A's
    would lose there what A lost too. The fired datagram's frame position is f: a cut starts
    at the first datagram at f + 1 or beyond, a restore at f (that datagram passes), on every
    link named. In the other direction they take effect at each link's next datagram. The
    next step counts only once the step's cuts and restores of its own direction took
    effect."""

    def __init__(self, group: linkemu.LinkGroup, steps: list, log_path: str):
        self.group = group
        self.steps = steps
        self.next = 0
        self.seen = 0
        self.pending: list = []      # [link, direction, action, first frame position]
        self.totals: dict = {}       # (link, direction, msgid) -> datagrams so far
        self.frames: dict = {}       # (link, direction) -> datagrams so far, no marker
        self.done: list = []
        self.log_path = log_path
        for link in group.links:
            for d in link.dirs.values():
                d.admit = self._wrap(link, d, d.admit)

    def _wrap(self, link, direction, admit):
        def wrapped(data, now, rel, have_peer=True):
            i = direction.index                  # the index this datagram gets
            here = (link.name, direction.name)
            f = self.frames.get(here, 0)         # its frame position
            if tlog.count_marker(data) is None:
                self.frames[here] = f + 1
            key = (link.name, direction.name, msgid_of(data))
            self.totals[key] = self.totals.get(key, 0) + 1
            step = self._match(link.name, direction.name, data)
            if step is not None:
                for action, target in step["do"]:
                    for name in self.group.link(target).dirs:
                        at = (f if action == "restore" else f + 1) \
                            if name == direction.name else self.frames.get((target, name), 0)
                        self.pending.append([target, name, action, at])
                self.done.append(dict(step, index=i, frame=f, t=round(rel, 6)))
                self.write()
            for p in [p for p in self.pending if p[0] == link.name and p[1] == direction.name
                      and p[3] <= f]:
                self.pending.remove(p)
                (self._restore if p[2] == "restore" else self._cut)(direction, rel)
            return admit(data, now, rel, have_peer)
        return wrapped

    def _match(self, link: str, direction: str, data: bytes):
        if self.next >= len(self.steps):
            return None
        step = self.steps[self.next]
        on = step["on"]
        if on["link"] != link or on["dir"] != direction or msgid_of(data) != on["msgid"]:
            return None
        if any(p[1] == direction for p in self.pending):
            return None                          # the previous step is still taking effect
        self.seen += 1
        done = self.totals[(link, direction, on["msgid"])] if on.get("total") else self.seen
        if done < on["count"]:
            return None
        self.next += 1
        self.seen = 0
        return step

    @staticmethod
    def _cut(d, rel: float) -> None:
        # This datagram (admitted at rel) and every later one fall inside [rel, inf).
        if not (d.cfg.outage and d.cfg.outage[-1][1] == math.inf):
            d.cfg.outage = list(d.cfg.outage) + [(rel, math.inf)]

    @staticmethod
    def _restore(d, rel: float) -> None:
        if d.cfg.outage and d.cfg.outage[-1][1] == math.inf:
            start, _ = d.cfg.outage[-1]
            d.cfg.outage[-1] = (start, rel - start)   # the datagram at `rel` passes

    def write(self) -> None:
        with open(self.log_path, "w") as f:
            for r in self.done:
                f.write(json.dumps(r) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--group", required=True)
    ap.add_argument("--cuts", required=True)
    ap.add_argument("--cut-log", required=True)
    a = ap.parse_args()
    steps = json.loads(Path(a.cuts).read_text())
    group = linkemu.LinkGroup(linkemu.load_group_spec(a.group))
    names = {link.name for link in group.links}
    for s in steps:
        on = s.get("on", {})
        if (on.get("dir") not in ("up", "down") or on.get("link") not in names
                or not isinstance(on.get("count"), int) or on["count"] < 1
                or not s.get("do") or any(act not in ("cut", "restore") or l not in names
                                          for act, l in s["do"])):
            ap.error(f"bad step {s} (links: {sorted(names)})")
    cutter = Cutter(group, steps, a.cut_log)
    signal.signal(signal.SIGTERM, lambda *_: group.request_stop())
    signal.signal(signal.SIGINT, lambda *_: group.request_stop())
    signal.signal(signal.SIGUSR1, lambda *_: group.request_dump())
    for link in group.links:
        print(f"linkemu: link {link.name}: {link.banner()}", file=sys.stderr)
    group.on_start = lambda: print(f"linkemu: group of {len(group.links)} links listening",
                                   file=sys.stderr, flush=True)
    group.run()
    group.dump()
    cutter.write()
    group.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
