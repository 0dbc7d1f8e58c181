import pytest

from service.cli import COMMANDS, _command_in, build_parser, main


def test_every_command_has_help_and_parses(capsys):
    parser = build_parser()
    for name in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            parser.parse_args([name, "--help"])
        assert exc.value.code == 0
        assert f"contourcap {name}" in capsys.readouterr().out


def test_only_the_named_command_is_built():
    assert _command_in(["--version"]) is None
    assert _command_in(["export", "x.jsonl"]) == "export"
    assert _command_in(["nonsense"]) is None
    parser = build_parser("export")
    args = parser.parse_args(["export", "poses.jsonl", "--bvh", "out.bvh"])
    assert args.command == "export" and callable(args._run)


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out
