"""Every config field and CLI option is documented, and the committed reference is current."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from capsule_mpc.cli import build_parser
from capsule_mpc.cli.reference import iter_config_fields, write_reference_docs

DOCS = Path(__file__).resolve().parents[1] / "docs"


@pytest.mark.parametrize(("path", "desc"), [(r[0], r[3]) for r in iter_config_fields()])
def test_every_config_field_has_a_description(path, desc):
    assert len(desc) > 10, f"config field {path} has no description"


def _subparsers(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """Every command and sub-command's parser, by its words (``rig serve``)."""
    found = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found[f"{prefix}{name}"] = sub
                found.update(_subparsers(sub, f"{prefix}{name} "))
    return found


@pytest.mark.parametrize(("command", "sub"), list(_subparsers(build_parser()).items()))
def test_every_cli_option_has_help(command, sub):
    for action in sub._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help, (
            f"capsule-mpc {command}: option {action.option_strings or action.dest} has no help"
        )


def test_committed_reference_is_current(tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    for fresh in write_reference_docs(tmp_path):
        committed = DOCS / fresh.name
        assert committed.exists(), f"docs/{fresh.name} missing: run `capsule-mpc docs`"
        assert committed.read_text() == fresh.read_text(), (
            f"docs/{fresh.name} is stale: run `capsule-mpc docs`"
        )


def _commands(parser: argparse.ArgumentParser, prefix: str = "capsule-mpc") -> list[str]:
    """Every command and sub-command of ``parser``, as typed (``capsule-mpc rig serve``)."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += [f"{prefix} {name}", *_commands(sub, f"{prefix} {name}")]
    return found


def test_the_reference_has_a_section_for_every_command_and_sub_command():
    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    commands = _commands(build_parser())
    assert {"capsule-mpc rig serve", "capsule-mpc log export", "capsule-mpc simulate"} <= set(commands)
    assert [c for c in commands if f"## `{c}`" not in text] == []
