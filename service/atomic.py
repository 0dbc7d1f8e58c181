"""Atomic file outputs for the service (poses, exports, reviews): see :mod:`capture.atomic`.

The implementation lives in ``capture/`` because the recorder, calibration and session writers use it
too and ``capture`` imports nothing from ``service``.
"""

from capture.atomic import PARTIAL, JsonlWriter, atomic_open, atomic_path, write_bytes_atomic, write_text_atomic

__all__ = ["atomic_open", "atomic_path", "write_text_atomic", "write_bytes_atomic", "JsonlWriter", "PARTIAL"]
