"""Live pipeline benchmark: the demo studio over zenoh on loopback, workers as processes.

Prints the figures of issue 6 ``{"cameras","fps_in","fps_out","realtime_factor","latency_ms_p50",
"latency_ms_p99","dropped_sets","cpu_percent"}`` plus ``frames``/``ok`` (how many poses, how many
solved), ``poses_per_s`` (live: poses over the replay window; ``fps_out`` is the rate between the
first and the last pose), ``mean_joint_error_m`` (against the synthetic ground truth: a pipeline that keeps up by
losing the track is no good) and where the time goes: ``cpu_by_component`` (percent of one core,
over the run, per worker role — camera, segment, track — and ``hub``: this process, which records
the poses and bridges them to rerun; live, frames and chamfers only with ``--image-cameras N``) (``--json``) or a table.  ``--live`` replays in
real time (the tracker demands the frames it can take); the default is lossless (every frame,
back-pressure) which measures throughput.  ``--fit-plugin tests.test_service_plugins:fitter_factory``
measures the transport and segmentation without the tracker.  ``cpu_ms_per_pose``: CPU of the
whole pipeline (workers and this process) per pose, ``fit_ms_p50``: the median fit time (pose
records' ``fit_ms``) and ``fit_cpu_ms_p50`` its CPU time (``fit_cpu_ms``: ``fit_ms`` less the time the
track worker waited for a core; ``fit_cpu_ms_mean`` its mean, ``rejoin_sets`` the sets that ran the
in-set rejoin) — figures that a machine shared with other work changes less than the
wall-clock ones.  Live, ``cpu_by_component_replay`` is ``cpu_by_component`` over the replay window only
(session time 0 to its end: the start-up's decoding and compiling left out) and
``cpu_ms_per_set_by_component`` that CPU per published pose, milliseconds.  Live, the replay cameras hold the clip decoded in memory as the demo's do (when
it takes at most 1 GB decoded; ``--preload``: whatever its size; ``--decode-live``: never), so
``cpu_by_component.camera`` is the cost of publishing frames, not of decoding the session's videos.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse
import json
import os

import numpy as np
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402

from service.commands import demo as demo_cmd  # noqa: E402
from service.demo import run_demo  # noqa: E402

KEYS = ("cameras", "fps_in", "fps_out", "realtime_factor", "latency_ms_p50", "latency_ms_p99", "dropped_sets",
        "cpu_percent", "frames", "ok", "mean_joint_error_m")
TICK = os.sysconf("SC_CLK_TCK")


def _role(cmdline: list[str]) -> str | None:
    """The worker role of a ``service.commands.worker ROLE ...`` command line, else None."""
    if "service.commands.worker" in cmdline:
        i = cmdline.index("service.commands.worker")
        return cmdline[i + 1] if i + 1 < len(cmdline) else None
    return None


def _cpu_s(pid: int | str) -> float:
    """User + system CPU seconds of one process (fields 14 and 15 of /proc/PID/stat)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / TICK


class CpuSampler:
    """CPU seconds per worker role of this process's children, sampled every ``period_s`` (a worker
    that exits keeps its last sample; its final ~``period_s`` of CPU is not counted), and each
    sample's role totals with its wall-clock time (``series``: ``(time_ns, {role: cpu_s})``, this
    process as ``"hub"``)."""

    def __init__(self, period_s: float = 0.25) -> None:
        self.period_s, self.parent = period_s, os.getpid()
        self.last: dict[int, tuple[str, float]] = {}
        self.series: list[tuple[int, dict[str, float]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _children(self) -> list[Path]:
        """This process's children (``/proc/PID/task/*/children``; every process when unavailable)."""
        try:
            pids = {p for task in Path(f"/proc/{self.parent}/task").iterdir()
                    for p in (task / "children").read_text().split()}
            return [Path("/proc") / p for p in sorted(pids)]
        except OSError:
            return [p for p in Path("/proc").iterdir() if p.name.isdigit()]

    def _sample(self) -> None:
        for proc in self._children():
            try:
                stat = (proc / "stat").read_text()
                ppid = int(stat[stat.rindex(")") + 2:].split()[1])
                if ppid != self.parent:
                    continue
                role = _role((proc / "cmdline").read_bytes().decode(errors="replace").split("\0"))
                if role is not None:
                    self.last[int(proc.name)] = (role, _cpu_s(proc.name))
            except (OSError, ValueError, IndexError):
                continue  # exited meanwhile
        self.series.append((time.time_ns(), self._by_role(_cpu_s(os.getpid()))))

    def _by_role(self, hub_s: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for role, cpu in self.last.values():
            out[role] = out.get(role, 0.0) + cpu
        out["hub"] = hub_s
        return out

    def between(self, start_ns: int, end_ns: int) -> tuple[dict[str, float], float] | None:
        """CPU seconds per role from the last sample at or before ``start_ns`` to the last at or before
        ``end_ns``, and the wall seconds between those samples (None: no such pair)."""
        first = [s for s in self.series if s[0] <= start_ns]
        last = [s for s in self.series if s[0] <= end_ns]
        if not first or not last or last[-1][0] <= first[-1][0]:
            return None
        (t0, a), (t1, b) = first[-1], last[-1]
        return {k: b[k] - a.get(k, 0.0) for k in sorted(b)}, (t1 - t0) / 1e9

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def __enter__(self) -> "CpuSampler":
        self.t0, self.self0 = time.monotonic(), _cpu_s(os.getpid())
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.wall = time.monotonic() - self.t0
        self.self_s = _cpu_s(os.getpid()) - self.self0

    def total_s(self) -> float:
        """CPU seconds of the workers and this process over the run."""
        return sum(cpu for _, cpu in self.last.values()) + self.self_s

    def percent(self) -> dict[str, float]:
        out = self._by_role(self.self_s)
        return {k: round(100.0 * v / self.wall, 1) for k, v in sorted(out.items())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    demo_cmd.add_args(parser)
    parser.add_argument("--preload", action="store_true",
                        help="live: camera workers decode the session into memory before streaming it (a camera "
                             "that delivers decoded frames; without it the replay's FFV1 decoding is measured too)")
    parser.add_argument("--start-delay-s", type=float, default=None,
                        help="live: seconds from starting the workers to session time 0 (default the demo's); "
                             "a loaded machine needs longer to start large studios")
    opts = parser.parse_args(argv)
    ref_ms = machine_ref_ms()
    with tempfile.TemporaryDirectory() as tmp:
        if opts.out is None:
            opts.out = tmp
        with CpuSampler() as cpu:
            demo_opts = demo_cmd.options_from_args(opts)
            if opts.start_delay_s is not None:
                demo_opts = replace(demo_opts, live_start_delay_s=opts.start_delay_s)
            if opts.preload:  # whatever the decoded clip's size (the demo's own limit is 1 GB)
                demo_opts = replace(demo_opts, live_preload_mb=float("inf"))
            summary = run_demo(demo_opts, progress=lambda m: print(m, file=sys.stderr))
        records = [json.loads(line) for line in Path(summary.poses).read_text().splitlines()]
        fits = [r["fit_ms"] for r in records if r.get("fit_ms") is not None]
        fit_cpu = [r["fit_cpu_ms"] for r in records if r.get("fit_cpu_ms") is not None]
    result = {k: summary.as_dict()[k] for k in KEYS}
    # fps_out is the rate between the first and the last pose (a burst after a long start-up looks fast):
    # live, also poses over the whole replay window
    result["poses_per_s"] = round(summary.frames / opts.duration_s, 2) if opts.live else None
    result["cpu_by_component"] = cpu.percent()
    window = cpu.between(*summary.replay_ns) if summary.replay_ns is not None else None
    if window is not None:  # live: the replay window alone (no start-up decoding or compiling)
        by_role, wall = window
        result["cpu_by_component_replay"] = {k: round(100.0 * v / wall, 1) for k, v in by_role.items()}
        result["cpu_ms_per_set_by_component"] = ({k: round(1e3 * v / summary.frames, 2) for k, v in by_role.items()}
                                                 if summary.frames else None)
    # CPU per pose of the whole pipeline: comparable across runs on a loaded machine, where the wall-clock
    # figures follow the share of the cores the pipeline gets
    result["cpu_ms_per_pose"] = round(1e3 * cpu.total_s() / summary.frames, 1) if summary.frames else None
    result["fit_ms_p50"] = round(float(np.percentile(fits, 50)), 2) if fits else None
    result["fit_cpu_ms_p50"] = round(float(np.percentile(fit_cpu, 50)), 2) if fit_cpu else None
    # the mean (in-set rejoins included) against cpu_ms_per_set_by_component["track"]: the rest of the track
    # worker's CPU per set is its background searches, the transport's threads and its loop
    result["fit_cpu_ms_mean"] = round(float(np.mean(fit_cpu)), 2) if fit_cpu else None
    result["rejoin_sets"] = sum("rejoin_ms" in r for r in records)
    result["wall_s"] = round(summary.wall_s, 1)
    result["machine_ref_ms"] = round(ref_ms, 2)
    if opts.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:18s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
