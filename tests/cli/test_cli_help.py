"""Every command's ``--help`` is plain text (no reST markup), and every option has help that shows its default."""

import argparse
import importlib
import subprocess
import sys

import pytest

from gof_warp.cli import COMMANDS
from gof_warp.cli import main as dispatcher_main

MARKUP = ("``", ":func:", ":mod:", ":class:", ":meth:", "**")


def _help(command: str, monkeypatch, capsys) -> tuple[str, list[argparse.ArgumentParser]]:
    """``gof-warp <command> --help``: its output, and the parser(s) that printed it."""
    printed = []
    original = argparse.ArgumentParser.print_help

    def record(self, file=None):
        printed.append(self)
        return original(self, file)

    monkeypatch.setattr(argparse.ArgumentParser, "print_help", record)
    module = importlib.import_module(f"gof_warp.cli.{COMMANDS[command][0]}")
    with pytest.raises(SystemExit) as exit_:
        module.main(["--help"])
    assert exit_.value.code in (0, None)
    return capsys.readouterr().out, printed


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_is_plain_text(command, monkeypatch, capsys):
    out, _ = _help(command, monkeypatch, capsys)
    assert out.startswith("usage:")
    found = [m for m in MARKUP if m in out]
    assert not found, f"{command} --help shows reST markup {found}:\n{out}"


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_option_has_help_showing_its_default(command, monkeypatch, capsys):
    _, parsers = _help(command, monkeypatch, capsys)
    assert len(parsers) == 1
    parser = parsers[0]
    formatter = parser._get_formatter()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        text = formatter._expand_help(action) if action.help else ""
        assert text.strip(), f"{command}: {action.option_strings or action.dest} has no help"
        takes_value = action.option_strings and action.nargs != 0 and not action.required
        if takes_value or isinstance(action, argparse.BooleanOptionalAction):
            assert "default" in text.lower(), f"{command}: {action.option_strings} does not show its default: {text!r}"


def test_dispatcher_help(capsys):
    assert dispatcher_main(["--help"]) == 0
    out = capsys.readouterr().out
    assert not [m for m in MARKUP if m in out]
    assert all(name in out for name in COMMANDS)


def test_module_help_through_the_shim():
    """``python -m gof_warp.extract --help`` (the shim) prints the grouped options, the common ones first."""
    proc = subprocess.run([sys.executable, "-m", "gof_warp.extract", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    groups = [out.index(g) for g in ("common options:", "grid and search:", "advanced and performance",
                                     "other outputs:")]
    assert groups == sorted(groups)
    def line(option):  # where the option's help entry starts (not its mention in the usage)
        return out.index(f"\n  {option} ")

    assert groups[0] < line("--max-faces") < groups[1] < line("--binary-steps") < groups[2]
    assert groups[2] < line("--piece-tets") < groups[3] < line("--voxel-size")
