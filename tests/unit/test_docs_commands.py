"""Every ``ubitrack`` command the README and ``docs/`` print is one the command line takes
(issue 31: a new user follows only the README), and every ``python -m bench.NAME`` they name
is a benchmark.

A line of a shell block is an invocation: the command line's own parser
(``ubitrack_agent.cli.build_parser``) must accept it whole (it exits on an unknown
subcommand, an unknown option, a missing argument or a value of the wrong kind). An inline code
span often names a command or one of its options in prose (`ubitrack host --cores`), so there
the subcommands and option names must exist. Nothing is run.
"""

from __future__ import annotations

import argparse
import functools
import re
import shlex
from pathlib import Path

import pytest

from ubitrack_agent import cli

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_BLOCK = re.compile(r"```(?:sh|bash|console|shell)?\n(.*?)```", re.DOTALL)
INLINE_CODE = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
COMMAND = re.compile(r"^(?:\S*/)?(?:ubitrack|python3? -m bench\.\w+)(?:\s|$)")
SYNOPSIS = re.compile(r"\$|\[|\.\.\.")
"""A shell variable, an optional part or an ellipsis: a synopsis, not an invocation."""


def _commands_in(text: str) -> list[tuple[str, bool]]:
    """``(command, whole)`` for each command line of ``text``: a shell block's lines
    (continuations joined; each command of a pipe or list, a trailing ``&`` and comments
    dropped; ``whole``) and inline spans (not ``whole``), those starting with ``ubitrack`` or
    ``python -m bench.``. A line is split as the shell would (``shlex``): a ``;`` inside quotes
    is an argument's."""
    lines = [
        (line, True)
        for block in SHELL_BLOCK.findall(text)
        for line in block.replace("\\\n", " ").splitlines()
    ]
    lines += [(span, False) for span in INLINE_CODE.findall(text.replace("\n", " "))]
    commands = []
    for line, whole in lines:
        for part in _shell_commands(line.strip().removeprefix("$ ")):
            if COMMAND.match(part):
                commands.append((part, whole and not SYNOPSIS.search(part)))
    return commands


def _shell_commands(line: str) -> list[str]:
    """The commands of a shell line, split at ``;``, ``|``, ``&``, ``&&``, ``||`` outside
    quotes, comments dropped; a line ``shlex`` cannot split (an open quote) is kept whole, so a
    command in it fails the check below rather than going unchecked."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";|&")
    lexer.whitespace_split = True
    try:
        tokens = list(lexer)
    except ValueError:
        return [line]
    commands: list[list[str]] = [[]]
    for token in tokens:
        if set(token) <= set(";|&"):
            commands.append([])
        else:
            commands[-1].append(token)
    return [shlex.join(words) for words in commands if words]


def documented_commands() -> list[tuple[str, str, bool]]:
    return [
        (str(path.relative_to(ROOT)), command, whole)
        for path in DOCUMENTS
        for command, whole in dict.fromkeys(_commands_in(path.read_text()))
    ]


@functools.cache
def build_parser() -> argparse.ArgumentParser:
    """The command line's parser, built once (parsing leaves it as it was)."""
    return cli.build_parser()


def _names_exist(parser: argparse.ArgumentParser, words: list[str]) -> str | None:
    """What of ``words`` (subcommands, then options) ``parser`` does not know, or ``None``."""
    for word in words:
        subcommands = parser._subparsers  # argparse keeps its subparsers there; no public API
        if word.startswith("-"):
            if word.split("=", 1)[0] not in parser._option_string_actions:
                return f"no option {word} in `{parser.prog}`"
        elif subcommands is not None:
            (action,) = [a for a in subcommands._group_actions if a.choices]
            if word not in action.choices:
                return f"no subcommand {word} in `{parser.prog}`"
            parser = action.choices[word]
    return None


def test_the_documents_hold_commands_to_check():
    found = documented_commands()
    assert {"README.md", "docs/performance.md"} <= {document for document, *_ in found}
    assert sum(whole for *_, whole in found) > 20 and len(found) > 100


@pytest.mark.parametrize(("document", "command", "whole"), documented_commands())
def test_a_documented_command_is_one_the_command_line_takes(document, command, whole, capsys):
    words = shlex.split(command)
    if words[0].startswith("python"):
        module = words[2].removeprefix("bench.")
        assert (ROOT / "bench" / f"{module}.py").is_file(), f"{document}: no bench/{module}.py"
        return
    if not whole:
        assert _names_exist(build_parser(), words[1:]) is None, f"{document}: `{command}`"
        return
    try:
        build_parser().parse_args(words[1:])
    except SystemExit as exc:
        if exc.code != 0:  # 0: --help in the line
            pytest.fail(f"{document}: `{command}`: {capsys.readouterr().err.strip()}")


def test_a_mistyped_command_is_caught():
    """Both checks can fail: a misspelt option, a missing argument, an unknown subcommand."""
    for words in (["subscribe", "C", "A", "--tpye", "6D"], ["plan"], ["demo", "--phases", "3"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args(words)
    assert _names_exist(build_parser(), ["sim", "arts"]) is not None
    assert _names_exist(build_parser(), ["host", "--core"]) is not None
    assert _names_exist(build_parser(), ["sim", "art", "--clock-offset-ms"]) is None
