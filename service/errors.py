"""The one error type every ``service`` error derives from.

``contourcap``'s command line catches it once (``service/cli.py``) and prints its message, which names
the file, camera, key or option and what was wrong, as one line (exit 2; ``--debug`` adds the traceback).
"""

from __future__ import annotations

__all__ = ["ServiceError"]


class ServiceError(Exception):
    """Bad input met by ``service``: the message names what (path, camera, key, option) and why."""
