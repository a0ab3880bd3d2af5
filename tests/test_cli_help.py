"""`uqdrive --help` and every command's help read as a person reads them: each command listed with a line saying what
it does, each description a whole sentence, every argument explained."""

import re

import pytest

from uqdrive.bench import available
from uqdrive.tools.cli import COMMANDS, main

ARGPARSE_COMMANDS = (
    "bound",
    "certify",
    "findings",
    "headline",
    "frames",
    "plots-page",
    "redecide",
    "replay",
)  # `bench` routes to its benchmarks' own parsers
SECTION = re.compile(r"^(positional arguments|options):$")


def help_text(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    try:
        assert main([*argv, "--help"]) == 0
    except SystemExit as stopped:  # argparse's --help
        assert stopped.code == 0
    return capsys.readouterr().out


def incomplete(text: str) -> list[str]:
    """What an argparse help leaves unsaid: a description that stops mid-sentence, an argument with no help."""
    paragraphs = text.split("\n\n")
    description = " ".join(paragraphs[1].split()) if len(paragraphs) > 1 and not SECTION.match(paragraphs[1]) else ""
    found = [] if description.endswith((".", ")")) else [f"description not a whole sentence: {description!r}"]
    lines = text.splitlines()
    for i, line in enumerate(lines):
        entry = re.match(r"^  (\S.*)$", line)
        if entry is None or SECTION.match(line):
            continue
        continued = i + 1 < len(lines) and re.match(r"^ {4,}\S", lines[i + 1])
        if not re.search(r"\S {2,}\S", entry.group(1)) and not continued:
            found.append(f"no help for {entry.group(1).strip()!r}")
    return found


def test_uqdrive_help_lists_every_command_with_what_it_does(capsys):
    text = help_text(capsys)
    for name in COMMANDS:
        (line,) = [line for line in text.splitlines() if line.split()[:1] == [name]]
        assert len(line.split(maxsplit=1)) == 2, line
    columns = {line.index(help_) for line in text.splitlines() for _, help_ in COMMANDS.values() if help_ in line}
    assert len(columns) == 1  # the descriptions start in one column


@pytest.mark.parametrize("command", ARGPARSE_COMMANDS)
def test_every_commands_help_is_complete(capsys, command):
    assert not incomplete(help_text(capsys, command))


def test_uqdrive_bench_help_says_what_each_benchmark_measures(capsys):
    text = help_text(capsys, "bench")
    for name in available():
        (line,) = [line for line in text.splitlines() if line.split()[:1] == [name]]
        assert len(line.split()) >= 4, line


@pytest.mark.parametrize("benchmark", available())
def test_every_benchmarks_help_is_complete(capsys, benchmark):
    assert not incomplete(help_text(capsys, "bench", benchmark))


def test_the_check_finds_a_description_cut_mid_sentence_and_an_unexplained_argument():
    text = "usage: x [-h] [--seed SEED]\n\nThe findings, rendered from\n\noptions:\n  -h, --help  show\n  --seed SEED\n"
    assert incomplete(text) == [
        "description not a whole sentence: 'The findings, rendered from'",
        "no help for '--seed SEED'",
    ]
