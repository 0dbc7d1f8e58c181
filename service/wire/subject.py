"""A fitted subject on the wire (``contourcap/<studio>/subject``): subject-file TOML text.

The payload is the UTF-8 text of a subject file (DESIGN.md, ``tracker.body.subject``), readable by
any TOML parser, at most :data:`SUBJECT_MAX_BYTES`.  :meth:`SubjectMessage.from_bytes` validates it
as ``read_subject`` validates a file (model known, sizes in range, tables bounded) and raises only
:class:`~service.wire.messages.MessageError`.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

from service.wire.messages import MessageError
from tracker.body.model import ModelError
from tracker.body.subject import Subject, parse_subject, subject_toml

__all__ = ["SUBJECT_MAX_BYTES", "SubjectMessage", "read_subject_message"]

SUBJECT_MAX_BYTES = 16 * 1024


@dataclass(frozen=True)
class SubjectMessage:
    """A validated subject and the TOML text it came as."""

    subject: Subject
    text: str

    @classmethod
    def of(cls, subject: Subject) -> "SubjectMessage":
        """The message of ``subject`` (its subject-file text, validated as a reader would)."""
        return cls.from_bytes(subject_toml(subject).encode("utf-8"))

    def to_bytes(self) -> bytes:
        """The wire bytes: the TOML text, UTF-8."""
        return self.text.encode("utf-8")

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = SUBJECT_MAX_BYTES) -> "SubjectMessage":
        """Decode and validate untrusted wire bytes; MessageError names the key at fault."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise MessageError(f"subject: expected bytes, got {type(data).__name__}")
        if len(data) > max_bytes:
            raise MessageError(f"subject: {len(data)} bytes exceeds the maximum of {max_bytes}")
        try:
            text = bytes(data).decode("utf-8")
            doc = tomllib.loads(text)
        except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
            raise MessageError(f"subject: not UTF-8 TOML ({exc.__class__.__name__}: {exc})"[:200]) from None
        try:
            subject = parse_subject(doc, "subject message")
        except ModelError as exc:
            raise MessageError(str(exc)[:300]) from None
        return cls(subject, text)


def read_subject_message(data: bytes, *, max_bytes: int = SUBJECT_MAX_BYTES) -> Subject:
    """The subject of a ``contourcap/<studio>/subject`` message, validated (MessageError otherwise)."""
    return SubjectMessage.from_bytes(data, max_bytes=max_bytes).subject
