"""Printing strings that came from outside (the network, a file a user supplied) on a terminal.

A received string may hold terminal escape sequences (``ESC [ 2 J`` clears the screen, OSC 52 writes
the clipboard, bidirectional overrides reorder what is shown); :func:`printable` shows every such
character as a visible escape, so what is printed is exactly what was received and nothing more.
"""

from __future__ import annotations

import re

__all__ = ["printable"]

# C0 controls, DEL, C1 controls, and the Unicode format characters that reorder or hide text
# (bidi embeddings/overrides/isolates, zero-width marks, line/paragraph separators)
_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2066-\u2069\ufeff]")


def _escape(m: re.Match) -> str:
    c = ord(m.group(0))
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def printable(text, *, limit: int = 200) -> str:
    """``text`` (any object: ``str()`` of it) with every control/format character escaped
    (``\\x1b``, ``\\u202e``) and cut to ``limit`` characters (``…`` marks a cut)."""
    s = _UNSAFE.sub(_escape, str(text))
    return s if len(s) <= limit else s[: max(0, limit - 1)] + "…"
