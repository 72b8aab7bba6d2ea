#!/usr/bin/env python3
"""Generate MAVLink c_library_v2 from pymavlink's all.xml dialect (build-time step).

Usage: gen_c_library.py OUTPUT_DIR
Skips the work when OUTPUT_DIR already holds a library made from the same pymavlink version.
"""
import os
import sys

import pymavlink
from pymavlink.generator import mavgen


def main() -> int:
    out = sys.argv[1]
    xml = os.path.join(os.path.dirname(pymavlink.__file__), "dialects", "v20", "all.xml")
    stamp = os.path.join(out, ".pymavlink-version")
    version = getattr(pymavlink, "__version__", "unknown")
    if os.path.exists(stamp) and open(stamp).read() == version and \
            os.path.exists(os.path.join(out, "all", "mavlink.h")):
        print(f"c_library_v2 up to date in {out} (pymavlink {version})")
        return 0
    opts = mavgen.Opts(out, wire_protocol="2.0", language="C", validate=True)
    import io, contextlib
    with contextlib.redirect_stdout(io.StringIO()):
        ok = mavgen.mavgen(opts, [xml])
    if not ok:
        print("mavgen failed", file=sys.stderr)
        return 1
    with open(stamp, "w") as f:
        f.write(version)
    print(f"generated c_library_v2 in {out} from {xml} (pymavlink {version})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
