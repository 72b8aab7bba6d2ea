"""linkemu.py, held at the start line: the sockets are bound and "listening on" is printed as
usual, then it waits for one line on stdin before its clock starts. Released together, a run's
emulators share their time origin to within a few ms, so an --outage hits the same frames in
every mode (started one after the other, Python's start-up spread them by 50-250 ms)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tools"))
import linkemu  # noqa: E402

_run = linkemu.LinkEmulator.run


def _gated_run(self):
    sys.stdin.readline()  # "go", or EOF when the runner gives up
    _run(self)


linkemu.LinkEmulator.run = _gated_run
sys.exit(linkemu.main())
