"""``contourcap run``: start this host's workers as processes, restart the ones that die, stop all cleanly.

A worker that exits with status 0 has *finished* (e.g. a replay ended) and is not restarted; any other
exit (crash, kill) is restarted after a back-off that doubles from ``backoff_s`` up to
``max_backoff_s`` and resets once the process has run ``stable_s``.  :meth:`Supervisor.stop` sends
SIGTERM to every child, waits ``grace_s``, then SIGKILLs what is left.

Processes of a host (:func:`plan_host`): the router (if ``[router] host`` is this host), one camera
worker per camera (a crashed camera does not take the others down) — or one for all the host's
cameras when they take frame ids from the USB trigger box, which a single process must own, or
when the host is small (:data:`SMALL_HOST_CPUS`) — one segment worker for all the host's cameras (none with
``[tracker] method = "blobs"``: that tracker reads the frames itself), and the tracker (if ``[tracker] host``
is this host).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

from service.config import StudioConfig
from service.workers.runtime import needs_trigger

log = logging.getLogger("contourcap.supervisor")

SMALL_HOST_CPUS = 2
"""A host with at most this many CPUs runs one camera process for all its cameras (``plan_host``)."""


@dataclass(frozen=True)
class ProcessSpec:
    """One child: a name for the logs and its argv."""

    name: str
    argv: tuple[str, ...]


@dataclass
class _Child:
    spec: ProcessSpec
    proc: subprocess.Popen | None = None
    started_s: float = 0.0
    restart_at_s: float | None = None
    backoff_s: float = 0.0
    restarts: int = 0
    finished: bool = False
    history: list = field(default_factory=list)


def plan_host(cfg: StudioConfig, config_path: str, host: str, *, hub: str | None = None,
              epoch_ns: int | None = None, idle_exit_s: float | None = None, segment_plugin: str | None = None,
              fit_plugin: str | None = None, loop_replay: bool = False, preload_replay: bool = False,
              camera_processes: str | None = None, python: str = sys.executable) -> list[ProcessSpec]:
    """The processes ``contourcap run`` starts on ``host`` (see the module docstring).

    Parameters
    ----------
    cfg : StudioConfig
    config_path : str
        The studio TOML the workers read.
    host : str
    hub : str, optional
        Peer mode: the supervisor's hub endpoint the workers connect to.
    epoch_ns : int, optional
        Live replay: wall-clock time (ns) at which session time 0 is due.
    idle_exit_s : float, optional
        Segment and track workers exit after this long without input (replays).
    segment_plugin, fit_plugin : str, optional
        ``module:callable`` replacing the segmenter / the tracker.
    loop_replay, preload_replay : bool
        Replay cameras loop the session; decode it into memory before streaming (``--preload``).
    camera_processes : {"per-camera", "one"}, optional
        One camera process per camera, or one for all the host's cameras; default: one on a host
        of at most :data:`SMALL_HOST_CPUS` CPUs (each process costs its start-up and scheduling
        there), else one per camera.  A trigger box always gets one.
    python : str
        Interpreter of the children.

    Returns
    -------
    list of ProcessSpec
    """
    worker = (python, "-m", "service.commands.worker")  # skips loading every other sub-command
    common = ("--config", str(config_path), "--host", host) + (("--hub", hub) if hub else ())
    specs = []
    if cfg.router_host == host:
        specs.append(ProcessSpec("router", (python, "-m", "service.commands.router", "--config", str(config_path))))
    cams = [c.name for c in cfg.cameras_on(host)]
    extra = (("--epoch-ns", str(epoch_ns)) if epoch_ns is not None else ()) + (("--loop",) if loop_replay else ())
    extra += ("--preload",) if preload_replay else ()
    one = needs_trigger(cfg, cams) or (camera_processes == "one" or camera_processes is None
                                       and (os.cpu_count() or 1) <= SMALL_HOST_CPUS)
    if one:  # a USB trigger box (one process owns it) or a small host: all the host's cameras in one
        specs.append(ProcessSpec("camera", worker + ("camera", "--cameras", ",".join(cams)) + common + extra))
    else:
        for cam in cams:
            specs.append(ProcessSpec(f"camera-{cam}", worker + ("camera", "--cameras", cam) + common + extra))
    idle = ("--idle-exit-s", str(idle_exit_s)) if idle_exit_s is not None else ()
    if cams and (cfg.method != "blobs" or fit_plugin):  # the blob tracker reads the frames itself
        plug = ("--plugin", segment_plugin) if segment_plugin else ()
        specs.append(ProcessSpec("segment", worker + ("segment", "--cameras", ",".join(cams)) + common
                                 + plug + idle))
    if cfg.tracker_host == host:
        plug = ("--plugin", fit_plugin) if fit_plugin else ()
        specs.append(ProcessSpec("track", worker + ("track",) + common + plug + idle))
    return specs


class Supervisor:
    """Keeps child processes running (see module docstring).  Not thread-safe: drive it from one thread.

    Parameters
    ----------
    specs : sequence of ProcessSpec
    backoff_s, max_backoff_s : float
        First and largest restart delay (seconds); the delay doubles per quick death.
    stable_s : float
        A child that ran this long before dying restarts after ``backoff_s`` again.
    grace_s : float
        :meth:`stop`: seconds between SIGTERM and SIGKILL.
    clock, popen, cwd, env
        Injected for tests; ``cwd`` / ``env`` of the children.
    """

    def __init__(self, specs: Sequence[ProcessSpec], *, backoff_s: float = 0.5, max_backoff_s: float = 10.0,
                 stable_s: float = 10.0, grace_s: float = 5.0, clock: Callable[[], float] = time.monotonic,
                 popen: Callable[..., subprocess.Popen] = subprocess.Popen, cwd: str | None = None,
                 env: dict | None = None) -> None:
        self.children = [_Child(s) for s in specs]
        self.backoff_s, self.max_backoff_s, self.stable_s, self.grace_s = backoff_s, max_backoff_s, stable_s, grace_s
        self._clock, self._popen, self._cwd, self._env = clock, popen, cwd, env

    def _spawn(self, child: _Child) -> None:
        child.proc = self._popen(list(child.spec.argv), cwd=self._cwd, env=self._env)
        child.started_s = self._clock()
        child.restart_at_s = None
        log.info("started %s (pid %d)", child.spec.name, child.proc.pid)

    def start(self) -> None:
        """Start every child."""
        for child in self.children:
            self._spawn(child)

    def poll(self) -> None:
        """Reap exits, schedule and perform restarts."""
        now = self._clock()
        for child in self.children:
            if child.finished:
                continue
            if child.proc is not None:
                rc = child.proc.poll()
                if rc is None:
                    continue
                child.history.append(rc)
                child.proc = None
                if rc == 0:
                    child.finished = True
                    log.info("%s finished", child.spec.name)
                    continue
                ran = now - child.started_s
                child.backoff_s = self.backoff_s if ran >= self.stable_s or not child.backoff_s \
                    else min(2 * child.backoff_s, self.max_backoff_s)
                child.restart_at_s = now + child.backoff_s
                log.warning("%s died (status %s after %.1f s); restarting in %.1f s", child.spec.name, rc, ran,
                            child.backoff_s)
            elif child.restart_at_s is not None and now >= child.restart_at_s:
                child.restarts += 1
                self._spawn(child)

    @property
    def all_finished(self) -> bool:
        """Every child exited with status 0."""
        return all(c.finished for c in self.children)

    def pid(self, name: str) -> int | None:
        """Process id of the running child ``name``, or None."""
        for c in self.children:
            if c.spec.name == name and c.proc is not None:
                return c.proc.pid
        return None

    def run(self, stop: threading.Event, *, poll_s: float = 0.1, until_finished: bool = False) -> None:
        """Start everything and supervise until ``stop`` (or all finished), then stop cleanly."""
        self.start()
        try:
            while not stop.is_set() and not (until_finished and self.all_finished):
                self.poll()
                stop.wait(poll_s)
        finally:
            self.stop()

    def stop(self) -> None:
        running = [c for c in self.children if c.proc is not None and c.proc.poll() is None]
        for c in running:
            c.proc.send_signal(signal.SIGTERM)
        deadline = self._clock() + self.grace_s
        for c in running:
            try:
                c.proc.wait(max(0.0, deadline - self._clock()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in %.1f s; killing it", c.spec.name, self.grace_s)
                c.proc.kill()
                c.proc.wait()
        for c in self.children:
            c.proc = None
