"""The subject on the wire (``contourcap/<studio>/subject``), the pose record's ``subject`` and the
studio options of the automatic calibration."""

from __future__ import annotations

import pytest

from service.config import ConfigError, parse_config
from service.wire.messages import MessageError
from service.wire.records import PoseRecord
from service.wire.subject import SUBJECT_MAX_BYTES, SubjectMessage, read_subject_message
from tracker.body.subject import Subject, read_subject, write_subject


def test_subject_message_round_trip_equals_the_file(tmp_path):
    sub = Subject("knossow40", 1.7, {"thigh": 0.44, "upper_arm": 0.3}, "test", {"hip_width": 0.17}, {"thigh": 1.1})
    msg = SubjectMessage.of(sub)
    assert read_subject_message(msg.to_bytes()) == sub
    write_subject(tmp_path / "s.toml", sub)
    assert (tmp_path / "s.toml").read_text(encoding="utf-8") == msg.text  # the message is the file's text
    assert read_subject(tmp_path / "s.toml") == sub


@pytest.mark.parametrize("data, match", [
    (b"\xff\xfe[subject]", "UTF-8 TOML"),
    (b"[subject\nmodel = 1", "UTF-8 TOML"),
    (b"[other]\nx = 1\n", r"\[subject\]"),
    (b"[subject]\nheight_m = 40.0\n", "height_m"),
    (b"[subject]\nmodel = \"no_such_model\"\n", "no_such_model"),
    (b"[subject]\n[subject.segment_lengths]\nthigh = -0.4\n", "segment_lengths"),
    (b"[subject]\nfitted = \"" + b"x" * 2000 + b"\"\n", "fitted"),
    (b"[subject]\n" + b"#" * (SUBJECT_MAX_BYTES + 1), "exceeds"),
])
def test_a_bad_subject_message_is_one_message_error(data, match):
    with pytest.raises(MessageError, match=match):
        SubjectMessage.from_bytes(data)


def test_pose_record_subject_field_is_validated():
    base = {"frame": 1, "timestamp_ns": 2, "ok": True}
    assert PoseRecord.from_dict({**base, "subject": "subject_auto.toml"}).get("subject") == "subject_auto.toml"
    for bad in (3, "", "x" * 201, None):
        with pytest.raises(MessageError, match="subject"):
            PoseRecord.from_dict({**base, "subject": bad})


def _studio(tracker: str) -> dict:
    import tomllib

    text = ('[studio]\nname = "lab"\n[[camera]]\nname = "cam0"\nhost = "a"\nbackend = "opencv"\nsource = "0"\n'
            f"[tracker]\n{tracker}\n")
    return tomllib.loads(text)


def test_auto_subject_options_in_studio_toml():
    cfg = parse_config(_studio(""), where="studio.toml")
    assert cfg.auto_subject and cfg.auto_subject_frames == 9 and cfg.auto_subject_nice == 10
    cfg = parse_config(_studio("auto_subject = false\nauto_subject_frames = 12\nauto_subject_nice = 5"),
                       where="studio.toml")
    assert (cfg.auto_subject, cfg.auto_subject_frames, cfg.auto_subject_nice) == (False, 12, 5)
    for bad in ("auto_subject = 1", "auto_subject_frames = 2", "auto_subject_nice = 40", "auto_subject_frames = 1.5"):
        with pytest.raises(ConfigError, match="tracker"):
            parse_config(_studio(bad), where="studio.toml")
