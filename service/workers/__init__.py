"""The workers (camera, segment, track) and how a studio config builds them.

- one class per worker: :mod:`~service.workers.camera`, :mod:`~service.workers.segment`,
  :mod:`~service.workers.track` (shared names in :mod:`~service.workers.base`; all three under
  :mod:`~service.workers.loops`)
- their parts: :mod:`~service.workers.components` (segmenter and tracker adapters),
  :mod:`~service.workers.sources`, :mod:`~service.workers.plugins`
- the process around them: :mod:`~service.workers.topology`, :mod:`~service.workers.signals`,
  :mod:`~service.workers.preflight`, :mod:`~service.workers.trigger`, :mod:`~service.workers.frame_ids`
  (all under :mod:`~service.workers.runtime`); the command is ``service/commands/worker.py``.
"""
