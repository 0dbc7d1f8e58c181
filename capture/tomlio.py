"""Minimal TOML writer for the files contourcap writes (calibration, session, configs).

Reading uses the standard library's ``tomllib``.  Writing supports what our
contracts use: nested tables, arrays of tables, strings, booleans, ints,
floats and (nested) lists of those.  Floats are written with ``repr`` so a
round trip is exact.
"""

from __future__ import annotations

import math
import sys
from typing import Any, Mapping

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["dumps", "loads", "load_file", "tomllib"]


def _key(k: str) -> str:
    if k and all(c.isalnum() or c in "-_" for c in k):
        return k
    return _string(k)


def _string(s: str) -> str:
    out = s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
    return f'"{out}"'


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return _string(v)
    if hasattr(v, "tolist"):  # numpy scalars and arrays
        v = v.tolist()
        return _value(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) > 0 and all(isinstance(x, Mapping) for x in v)


def _emit(table: Mapping[str, Any], prefix: str, lines: list[str]) -> None:
    scalars = [(k, v) for k, v in table.items() if not isinstance(v, Mapping) and not _is_table_array(v)]
    for k, v in scalars:
        if v is None:
            continue
        lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in table.items():
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, Mapping):
            lines.append("")
            lines.append(f"[{name}]")
            _emit(v, name, lines)
        elif _is_table_array(v):
            for item in v:
                lines.append("")
                lines.append(f"[[{name}]]")
                _emit(item, name, lines)


def dumps(data: Mapping[str, Any]) -> str:
    """Serialise a mapping to TOML text (``None`` values are omitted)."""
    lines: list[str] = []
    _emit(data, "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def loads(text: str) -> dict:
    """Parse TOML text (``tomllib.loads``)."""
    return tomllib.loads(text)


def load_file(path, *, error: type[Exception] | None = None, what: str = "file") -> dict:
    """Parse a TOML file.

    Without ``error``: raises ``FileNotFoundError`` when it is absent, and ``ValueError`` naming the file
    for anything else (a syntax error, bytes that are not UTF-8, a folder or an unreadable file).
    With ``error`` (e.g. ``CalibrationError``): every failure is that type, the absent file reading
    "<path>: <what> not found".
    """
    try:
        try:
            with open(path, "rb") as fh:
                return tomllib.load(fh)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: invalid TOML: {exc}") from exc
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: invalid TOML: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
        except FileNotFoundError:
            raise
        except OSError as exc:
            raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except FileNotFoundError:
        if error is None:
            raise
        raise error(f"{path}: {what} not found") from None
    except ValueError as exc:
        if error is None:
            raise
        raise error(str(exc)) from None
