"""Studio TOML: the shipped example parses; bad keys give one error naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.config import ConfigError, load_config

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "studio.example.toml"


def _write(tmp_path, text, password=True):
    (tmp_path / "secrets").mkdir(exist_ok=True)
    (tmp_path / "secrets" / "zenoh_password").write_text("s3cret\n")
    p = tmp_path / "studio.toml"
    p.write_text(text)
    return p


def test_example_parses(tmp_path):
    cfg = load_config(_write(tmp_path, EXAMPLE.read_text()))
    assert len(cfg.cameras) == 6 and cfg.hosts == ("host-a", "host-b")
    assert [c.name for c in cfg.cameras_on("host-b")] == ["cam3", "cam4", "cam5"]
    assert cfg.zenoh.password == "s3cret" and cfg.zenoh.tls_root_ca == str(tmp_path / "certs" / "ca.pem")
    assert cfg.tracker_host == "host-b" and cfg.router_host == "host-a" and cfg.delivery == "live"
    assert cfg.router.mode == "router" and cfg.router.config_file == str(tmp_path / "zenoh" / "router-tls.json5")


@pytest.mark.parametrize("old, new, key", [
    ('delivery = "live"', 'delivery = "sometimes"', "studio.delivery"),
    ('name = "cam4"', 'name = "cam0"', "camera[4].name"),
    ('encoding = "raw"\n\n[[camera]]\nname = "cam1"', 'encoding = "gif"\n\n[[camera]]\nname = "cam1"',
     "camera[0].encoding"),
    ('window = 8', 'window = "8"', "tracker.window"),
    ('mode = "client"', 'mode = "client"\nport = 3', "zenoh.port"),
    ('name = "lab"', 'name = "lab/../x"', "studio.name"),
    ('password_file = "secrets/zenoh_password"', 'password_file = "nope"', "zenoh.password_file"),
])
def test_errors_name_the_key(tmp_path, old, new, key):
    text = EXAMPLE.read_text()
    assert old in text
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load_config(_write(tmp_path, text.replace(old, new, 1)))


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(_write(tmp_path, "[studio\n"))


def test_capture_keys_shared_with_record(tmp_path):
    """One studio.toml serves `contourcap run` and `contourcap record`: the capture keys are accepted by both."""
    from capture.recorder import load_capture_config

    path = _write(tmp_path, EXAMPLE.read_text())
    cam0 = load_config(path).camera("cam0")
    assert (cam0.width, cam0.height, cam0.exposure) == (800, 600, -6.0)
    assert {c.name: c.width for c in load_capture_config(path).cameras}["cam0"] == 800
    record, service = load_capture_config(path), load_config(path)  # one reader: the same values
    assert (record.fps, record.trigger) == (service.trigger.fps, service.trigger.backend)
    assert [(c.name, c.backend, c.width, c.exposure) for c in record.cameras] == [
        (c.name, c.backend, c.width, c.exposure) for c in service.cameras]
    with pytest.raises(ConfigError, match=r"camera\[0\]\.width"):
        load_config(_write(tmp_path, EXAMPLE.read_text().replace("width = 800", "width = -800", 1)))
