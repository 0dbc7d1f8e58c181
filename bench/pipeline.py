"""Live pipeline benchmark: the demo studio over zenoh on loopback, workers as processes.

Prints ``{"cameras","fps_in","fps_out","realtime_factor","latency_ms_p50","latency_ms_p99",
"dropped_sets","cpu_percent"}`` (``--json``) or a table.  ``--live`` replays in real time (stale sets
dropped); the default is lossless (every frame, back-pressure) which measures throughput.
``--fit-plugin tests.test_service_plugins:fitter_factory`` measures the transport and segmentation
without the tracker.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.commands import demo as demo_cmd  # noqa: E402
from service.demo import run_demo  # noqa: E402

KEYS = ("cameras", "fps_in", "fps_out", "realtime_factor", "latency_ms_p50", "latency_ms_p99", "dropped_sets",
        "cpu_percent")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    demo_cmd.add_args(parser)
    opts = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if opts.out == "contourcap-demo":
            opts.out = tmp
        summary = run_demo(demo_cmd.options_from_args(opts), progress=lambda m: print(m, file=sys.stderr))
    result = {k: summary.as_dict()[k] for k in KEYS}
    if opts.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:18s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
