"""A camera worker's sources, built from the studio config by ``capture.backends.open_source``."""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from capture.backends import SourceSpec, open_source
from capture.sources import SourceBase
from service.config import StudioConfig
from service.workers.frame_ids import free_run_frame_ids
from service.workers.session import studio_session

__all__ = ["build_sources", "open_camera"]


def build_sources(cfg: StudioConfig, cameras: tuple[str, ...], *, mode: str, paced: bool = False,
                  frame_id_at: Callable[[int], int] | None = None, loop: bool = False,
                  preload: bool = False) -> dict[str, SourceBase]:
    """Open the sources of ``cameras`` (see :func:`open_camera`); if one fails, those opened are closed.

    Preloaded replays decode side by side in threads (one per CPU at most).

    Returns
    -------
    dict
        Camera name -> open source.
    """
    out: dict = {}

    def one(name: str) -> SourceBase:
        return open_camera(cfg, name, mode=mode, paced=paced, frame_id_at=frame_id_at, loop=loop, preload=preload)

    try:
        if preload and paced and len(cameras) > 1:  # decoding releases the GIL: the cameras side by side
            with ThreadPoolExecutor(max_workers=min(len(cameras), os.cpu_count() or 1)) as pool:
                futures = {name: pool.submit(one, name) for name in cameras}
            errors = []
            for name, fut in futures.items():
                if fut.exception() is None:
                    out[name] = fut.result()
                else:
                    errors.append(fut.exception())
            if errors:
                raise errors[0]
        else:
            for name in cameras:
                out[name] = one(name)
    except BaseException:  # release the cameras already opened
        for src in out.values():
            src.close()
        raise
    return out


def open_camera(cfg: StudioConfig, name: str, *, mode: str, paced: bool = False,
                frame_id_at: Callable[[int], int] | None = None, loop: bool = False,
                preload: bool = False) -> SourceBase:
    """One camera's source, opened.

    Parameters
    ----------
    cfg : StudioConfig
    name : str
        Camera name.
    mode : {"live", "lossless"}
        Delivery: a live replay is paced in real time, a lossless one as fast as credits allow.
    paced : bool
        Replays are paced by the caller (an ``EpochPacer``), so read fast.
    frame_id_at : callable (timestamp_ns) -> int, optional
        opencv: the trigger box's frame ids (box clock); None: :func:`free_run_frame_ids` at the
        camera's fps on wall-clock timestamps.
    loop : bool
        Replays restart at the end with increasing frame ids.
    preload : bool
        Paced replays are decoded into memory first (benchmarks: a camera delivering decoded frames).
    """
    cam = cfg.camera(name)
    if cam.backend == "replay":
        spec = SourceSpec(name, "replay")
        src = open_source(spec, session=studio_session(cfg), loop=loop, preload=preload and paced,
                          pacing="realtime" if mode == "live" and not paced else "fast")
    else:
        fps = cam.fps or cfg.trigger.fps
        spec = SourceSpec(name, "opencv", int(cam.source) if cam.source.isdigit() else cam.source,
                          width=cam.width, height=cam.height, fps=fps, exposure=cam.exposure)
        src = open_source(spec, clock=None if frame_id_at is not None else time.time_ns,  # a box keeps its own clock
                          frame_id_at=frame_id_at if frame_id_at is not None else free_run_frame_ids(fps))
    src.open()
    return src
