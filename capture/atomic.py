"""Atomic file outputs: a file contourcap writes appears whole or not at all.

Every writer goes through a temporary file *in the destination's folder* (same file system, so the
final ``os.replace`` is atomic), fsyncs it, renames it over the destination on success and removes it
on failure.  An existing file is therefore never truncated by a run that fails, and a reader never
sees a half-written file.

- :func:`atomic_open` — a context manager yielding an open file object (text or binary).
- :func:`atomic_path` — a context manager yielding a temporary *path* with the destination's suffix,
  for writers that open files themselves (``cv2.VideoWriter``, ``cv2.imwrite``, ``numpy.savez``).
- :func:`write_text_atomic`, :func:`write_bytes_atomic` — one-shot helpers.
- :class:`JsonlWriter` — pose records while tracking: every record is appended and flushed to
  ``OUT.partial`` (a kill leaves every finished frame there); :meth:`JsonlWriter.commit` fsyncs and
  renames it onto ``OUT``.  A run that ends early (:meth:`JsonlWriter.abandon`) never replaces an
  existing ``OUT``: its finished records stay in ``OUT.partial`` (named in the message), or, when
  ``OUT`` did not exist, are renamed onto it; a run that finished no record leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

__all__ = ["atomic_open", "atomic_path", "write_text_atomic", "write_bytes_atomic", "JsonlWriter", "PARTIAL"]

PARTIAL = ".partial"  # suffix of the pose file being written while tracking


def _fsync_dir(folder: Path) -> None:
    """Make a rename durable (a no-op where directories cannot be opened, e.g. Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _temp_in(path: Path) -> Path:
    """A fresh temporary file next to ``path`` with the same suffix (writers pick formats by it)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    return Path(tmp)


def _publish(tmp: Path, path: Path) -> None:
    """fsync ``tmp``'s data, rename it onto ``path``, fsync the folder; keep an existing file's mode."""
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    try:
        os.chmod(tmp, os.stat(path).st_mode & 0o7777)
    except FileNotFoundError:
        os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _umask() -> int:
    """The process umask, read without changing it (``os.umask`` would, for every thread); 0o022 if unknown."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


@contextlib.contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (same suffix); on a clean exit it is renamed onto
    ``path``, on an exception removed (``path`` untouched).  The writer must have closed the file
    before the block ends.  The folder must exist (OSError otherwise, nothing written)."""
    path = Path(path)
    tmp = _temp_in(path)
    try:
        yield tmp
        if not tmp.exists():
            raise OSError(f"{path}: the writer produced no file")
        _publish(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """``open(path, mode)`` through a temporary file renamed onto ``path`` when the block ends
    without an exception; ``mode`` is ``"w"``, ``"wt"`` or ``"wb"`` (``kwargs`` go to ``open``)."""
    if mode not in ("w", "wb", "wt"):
        raise ValueError(f"atomic_open: mode must be 'w', 'wt' or 'wb', got {mode!r}")
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()


def write_text_atomic(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_open(path, "w", encoding=encoding, newline="") as fh:
        fh.write(text)


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)


class JsonlWriter:
    """One line per record into ``OUT.partial``, flushed per record; see the module docstring.

    Parameters
    ----------
    path : path-like
        The final file (``OUT``).  Its folder is created.
    """

    def __init__(self, path) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.partial, "wb")
        self.count = 0

    def write(self, line: bytes) -> None:
        """Append one record (``line`` without its newline) and flush it to the OS."""
        self._fh.write(line.rstrip(b"\n") + b"\n")
        self._fh.flush()
        self.count += 1

    def commit(self) -> Path:
        """The run finished: ``OUT.partial`` becomes ``OUT`` (replacing it)."""
        self._fh.close()
        _publish(self.partial, self.path)
        return self.path

    def abandon(self) -> Path | None:
        """The run ended early: where its finished records are (None when there were none)."""
        self._fh.close()
        if self.count == 0:
            with contextlib.suppress(OSError):
                self.partial.unlink()
            return None
        if not self.path.exists():
            _publish(self.partial, self.path)
            return self.path
        with open(self.partial, "rb+") as fh:
            os.fsync(fh.fileno())
        return self.partial

    def __enter__(self) -> "JsonlWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        elif not self._fh.closed:
            self.abandon()
