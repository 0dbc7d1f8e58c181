"""Subject files: a fitted subject's body, written by ``contourcap calibrate subject``.

A subject file (DESIGN.md, ``subject.toml``) is TOML::

    [subject]
    model = "knossow40"            # the body model the lengths apply to
    height_m = 1.75                # the height the model's other sizes follow
    fitted = "..."                 # how it was fitted (free text)
    [subject.segment_lengths]      # metres, the model's ``segment`` names
    thigh = 0.46
    [subject.widths]               # optional, metres, the model's ``width`` names
    hip_width = 0.16
    [subject.radius_scale]         # optional, factors on the model's radius groups
    thigh = 1.1
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from capture.tomlio import dumps, load_file
from tracker.body.model import BodyModel, ModelError, load_model

__all__ = ["Subject", "read_subject", "parse_subject", "subject_toml", "write_subject"]


@dataclass(frozen=True)
class Subject:
    """A subject's body: model name, height (metres), segment lengths and widths (metres), radius
    factors and provenance (``load_model``'s keywords)."""

    model: str = "knossow40"
    height_m: float = 1.75
    segment_lengths: Mapping[str, float] = field(default_factory=dict)
    fitted: str = ""
    widths: Mapping[str, float] = field(default_factory=dict)
    radius_scale: Mapping[str, float] = field(default_factory=dict)

    def body(self) -> BodyModel:
        """The sized body model (``load_model``)."""
        return load_model(self.model, height_m=self.height_m, segment_lengths=dict(self.segment_lengths),
                          widths=dict(self.widths), radius_scale=dict(self.radius_scale))


def read_subject(path) -> Subject:
    """Read and validate a subject file; ModelError naming the file and the key on bad content."""
    path = Path(path)
    return parse_subject(load_file(path, error=ModelError, what="subject file"), str(path))


def parse_subject(data, where: str) -> Subject:
    """Validate a parsed subject TOML document (a dict); ModelError naming ``where`` and the key."""
    sub = data.get("subject") if isinstance(data, dict) else None
    if not isinstance(sub, dict):
        raise ModelError(f"{where}: no [subject] table")
    name = sub.get("model", "knossow40")
    height = sub.get("height_m", 1.75)
    if not isinstance(name, str) or not name:
        raise ModelError(f"{where}: [subject] model must be a model name")
    if isinstance(height, bool) or not isinstance(height, (int, float)) or not 0.5 <= height <= 2.6:
        raise ModelError(f"{where}: [subject] height_m must be metres in [0.5, 2.6], got {height!r}")
    tables = {}
    for key, what in (("segment_lengths", "segment names to positive metres"),
                      ("widths", "width names to positive metres"),
                      ("radius_scale", "radius groups to positive factors")):
        table = sub.get(key, {})
        if not isinstance(table, dict) or len(table) > 64 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < 10 for v in table.values()):
            raise ModelError(f"{where}: [subject.{key}] must map {what}")
        tables[key] = {str(k): float(v) for k, v in table.items()}
    fitted = sub.get("fitted", "")
    if not isinstance(fitted, str) or len(fitted) > 1000:
        raise ModelError(f"{where}: [subject] fitted must be text of at most 1000 characters")
    subject = Subject(name, float(height), tables["segment_lengths"], fitted, tables["widths"], tables["radius_scale"])
    try:
        subject.body()
    except ModelError as exc:
        raise ModelError(f"{where}: {exc}") from None
    return subject


def subject_toml(subject: Subject) -> str:
    """``subject`` as subject-file TOML text (what :func:`write_subject` writes)."""
    data = {"subject": {"model": subject.model, "height_m": round(float(subject.height_m), 4),
                        "fitted": subject.fitted,
                        "segment_lengths": {k: round(float(v), 4) for k, v in subject.segment_lengths.items()}}}
    for key in ("widths", "radius_scale"):
        table = getattr(subject, key)
        if table:
            data["subject"][key] = {k: round(float(v), 4) for k, v in table.items()}
    return dumps(data)


def write_subject(path, subject: Subject) -> None:
    """Write ``subject`` as a subject file at ``path``."""
    Path(path).write_text(subject_toml(subject), encoding="utf-8")
