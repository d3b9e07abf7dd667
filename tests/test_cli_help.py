"""Every subcommand's --help: each argument and option has a help text, no RST markup, the
exit codes in the epilog (walks the argparse parser objects)."""

import argparse
import re

import pytest

from derive.cli import build_parser, main

#: Markup of reStructuredText / Sphinx that has no place in a terminal help text.
RST = re.compile(r"``|:(func|mod|class|meth|attr|ref|doc):`|`[^`]+`_")


def _subparsers(parser):
    [action] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return action.choices


def _checked_texts(parser):
    """(where, text) of the description, epilog and every action's help of a parser."""
    yield "description", parser.description or ""
    yield "epilog", parser.epilog or ""
    for a in parser._actions:
        yield "/".join(a.option_strings) or a.dest, a.help


def test_there_are_subcommands():
    names = set(_subparsers(build_parser()))
    assert {"robots", "fk", "ik", "refine", "kernels", "plot", "classify", "appendix", "export",
            "generate", "bench"} <= names


@pytest.mark.parametrize("name", sorted(_subparsers(build_parser())))
def test_every_option_has_help_without_markup(name):
    sub = _subparsers(build_parser())[name]
    for where, text in _checked_texts(sub):
        assert text and text is not argparse.SUPPRESS and text.strip(), f"{name} {where}: no help text"
        assert not RST.search(text), f"{name} {where}: RST markup in {text!r}"
    rendered = sub.format_help()
    assert not RST.search(rendered)
    assert "Exit codes:" in rendered and "0  success" in rendered


def test_top_level_help():
    parser = build_parser()
    for where, text in _checked_texts(parser):
        assert text and not RST.search(text), where
    text = parser.format_help()
    assert "Exit codes:" in text and "--quat-order" in text and "``" not in text


def test_kernels_help_says_fk_and_ik(capsys):
    with pytest.raises(SystemExit) as info:
        main(["kernels", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "FK" in out and "IK" in out


@pytest.mark.parametrize("name", ["fk", "ik", "refine", "plot", "robots"])
def test_help_exits_0(name, capsys):
    with pytest.raises(SystemExit) as info:
        main([name, "--help"])
    assert info.value.code == 0
    assert "--json" in capsys.readouterr().out
