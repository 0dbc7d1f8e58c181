"""Fuzzing the studio.toml reader (issue 16): any bytes, and tables with the right keys holding values
of every type, give a ``ConfigError`` or a ``StudioConfig``, never another exception.
``pytest --fuzz-long`` runs 100x more examples."""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.config import ConfigError, StudioConfig, load_config, parse_config
from tests.support.fuzz import hostile_bytes, toml_tables

EXAMPLE = (Path(__file__).resolve().parents[2] / "deploy" / "studio.example.toml").read_bytes()
SLOW = settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@SLOW
@given(data=st.data())
def test_studio_reader_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("studio") / "studio.toml"
    path.write_bytes(data.draw(hostile_bytes(EXAMPLE)))
    try:
        assert isinstance(load_config(path), StudioConfig)
    except ConfigError:
        pass


@SLOW
@given(studio=toml_tables(("name", "delivery", "session", "calibration", "model", "jpeg_quality")),
       zenoh=toml_tables(("mode", "listen", "connect", "tls", "user", "password")),
       trigger=toml_tables(("device", "fps", "resync_s")),
       tracker=toml_tables(("host", "set_timeout_ms", "window")),
       cameras=st.lists(toml_tables(("name", "host", "backend", "source", "device", "width", "height", "fps",
                                     "encoding", "exposure")), max_size=3))
def test_studio_tables_with_wrong_types(studio, zenoh, trigger, tracker, cameras):
    try:
        parse_config({"studio": studio, "zenoh": zenoh, "trigger": trigger, "tracker": tracker, "camera": cameras},
                     where="fuzz.toml")
    except ConfigError:
        pass
