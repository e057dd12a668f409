"""Every command line's --help lists its options' choices and defaults: run in-process through each
CLI's main(["--help"]), and checked option by option against the parser that main uses."""

from __future__ import annotations

import argparse
import importlib
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
# The console scripts (pyproject.toml [project.scripts]) and the python -m commands: each has build_parser().
MODULES = ("tools.cli.sim", "tools.cli.serial", "tools.cli.klipper_mcu", "tools.cli.fit", "tools.cli.compare", "tools.cli.tune",
           "tools.cli.firmware_report", "tools.cli.benchfuncs", "tools.bench", "tools.seeds.__main__",
           "tools.docs.rules_table", "tools.docs.optimtable", "tools.docs.crossval", "tools.docs.mpc_report",
           "tools.docs.kalico_table", "tools.klipper_host.agent",
           "tools.docs.validation", "tools.validation.golden", "tools.validation.golden_m306",
           "tools.validation.plant_check", "tools.tuning.ultimate")


def _squeezed(text: str) -> str:
    return "".join(text.split())  # argparse wraps lines where it likes: compare without whitespace


def _shown_default(action: argparse.Action) -> str | None:
    """The default --help must show for this option, or None where there is nothing to show (no default, a
    flag's on/off, an empty list)."""
    default = action.default
    if default is None or default is argparse.SUPPRESS or isinstance(default, bool) or default == []:
        return None
    return str(default)


def _block(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    # argparse's own rendering of one option (its invocation and expanded help), as --help prints it
    return parser._get_formatter()._format_action(action)


def test_every_console_script_is_covered():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert {target.split(":")[0] for target in scripts.values()} <= set(MODULES)


@pytest.mark.parametrize("module_name", MODULES)
def test_help_lists_every_choice_and_default(module_name, capsys):
    module = importlib.import_module(module_name)
    try:
        status = module.main(["--help"])
    except SystemExit as exc:  # argparse's exit after --help (twin-tune's main returns the status instead)
        status = exc.code
    assert status in (0, None)
    printed = _squeezed(capsys.readouterr().out)
    parser = module.build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        block = _squeezed(_block(parser, action))
        assert block in printed, f"{action.dest}: its help is not in --help"
        name = "/".join(action.option_strings) or action.dest
        for choice in action.choices or ():
            assert _squeezed(str(choice)) in block, f"{module_name} {name}: choice {choice!r} not in its help"
        default = _shown_default(action)
        if default is not None:
            assert _squeezed(default) in block, f"{module_name} {name}: default {default!r} not in its help"
    assert parser.format_help()  # renders without a format error
