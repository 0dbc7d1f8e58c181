"""deploy/: every systemd ExecStart is a valid contourcap command line; the Containerfile copies paths
that exist."""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
from pathlib import Path

import pytest

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
MODULES = {"run": "run", "worker": "worker", "router": "router"}


def _units():
    return sorted((DEPLOY / "systemd").glob("*.service"))


@pytest.mark.parametrize("unit", _units(), ids=lambda p: p.name)
def test_systemd_execstart_parses(unit):
    text = unit.read_text()
    (line,) = re.findall(r"^ExecStart=(.*)$", text, re.M)
    argv = shlex.split(line.replace("%i", "cam0").replace("%H", "host-a"))
    assert argv[:2] == ["/usr/bin/env", "contourcap"]
    module = importlib.import_module(f"service.commands.{MODULES[argv[2]]}")
    parser = argparse.ArgumentParser()
    module.add_args(parser)
    args = parser.parse_args(argv[3:])
    assert args.config == "/etc/contourcap/studio.toml"
    assert "[Install]" in text and "WantedBy=multi-user.target" in text


def test_containerfile_copies_existing_paths():
    text = (DEPLOY / "container" / "Containerfile").read_text()
    sources = [s for line in re.findall(r"^COPY (.*)$", text, re.M) for s in line.split()[:-1]]
    assert sources and all((DEPLOY.parent / s).exists() for s in sources)
    assert re.search(r"^ENTRYPOINT \[\"contourcap\"\]", text, re.M)
