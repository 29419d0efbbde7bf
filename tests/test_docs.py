"""The manual holds together: README.md and docs/*.md link only to what exists, and every
``ogiflow ...`` command they show is accepted by the command line's argument parser.

Commands are parsed, not run (``appliance.cli.build_parser``). A command is a shell command
in a fenced block of shell code (``sh``, ``bash``, ``console`` or no language) or an inline
code span, whose command word is ``ogiflow`` (also as ``.venv/bin/ogiflow`` or after
``VAR=value`` assignments, ``&&``, ``;``, ``|``). An inline span made of command names only
(``ogiflow eval emission``, naming the command in prose) must name an existing command; any
other span or line must parse as it is written.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from appliance.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
SHELL_LANGUAGES = {"", "sh", "bash", "shell", "console"}
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
INLINE_CODE = re.compile(r"(`+)(.+?)\1")
FENCE = re.compile(r"^\s*(```+|~~~+)\s*([\w+-]*)")
SHELL_OPERATORS = {"&&", "||", ";", "|", "&", "(", ")"}


@dataclass(frozen=True)
class Line:
    """One line of a page, with what it is part of."""

    page: Path
    number: int
    text: str
    fence: str | None  # the language of the fenced block it is in, None outside blocks

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.number}"


def page_lines(page: Path) -> list[Line]:
    """Every line of ``page``, each marked with the fenced block it lies in (if any)."""
    lines: list[Line] = []
    fence: str | None = None
    marker = ""
    for number, text in enumerate(page.read_text().splitlines(), start=1):
        m = FENCE.match(text)
        if fence is None and m:
            fence, marker = m.group(2).lower(), m.group(1)
            continue
        if fence is not None and text.strip().startswith(marker[:3]) and \
                text.strip().strip(marker[0]) == "":
            fence = None
            continue
        lines.append(Line(page, number, text, fence))
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]{1,2}(?=\S)|(?<=\S)[`*_]{1,2}", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of every heading of ``page`` (repeated headings get -1, -2, ...)."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    for line in page_lines(page):
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line.text)
        if line.fence is not None or not m:
            continue
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def prose(text: str) -> str:
    """``text`` without its inline code spans (links in code are not links)."""
    return INLINE_CODE.sub("", text)


def links() -> Iterator[tuple[Line, str]]:
    for page in PAGES:
        for line in page_lines(page):
            if line.fence is None:
                for m in LINK.finditer(prose(line.text)):
                    yield line, m.group(1)


def link_problem(line: Line, target: str) -> str | None:
    """Why ``target`` (a link on ``line``) does not resolve, or None when it does."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):
        return None  # a URL (https:, mailto:, file:): not ours to check here
    path_part, _, anchor = target.partition("#")
    path = (line.page.parent / path_part).resolve() if path_part else line.page
    if not path.exists():
        return f"{target!r}: {path_part} does not exist"
    if anchor and path.suffix == ".md" and anchor not in anchors(path):
        return f"{target!r}: no heading with the anchor #{anchor} in {path.name}"
    return None


def logical_lines(lines: list[Line]) -> Iterator[tuple[Line, str]]:
    """Shell lines of a fenced block, with backslash continuations joined."""
    pending: Line | None = None
    text = ""
    for line in lines:
        if pending is None:
            pending, text = line, ""
        if line.text.rstrip().endswith("\\"):
            text += line.text.rstrip()[:-1] + " "
            continue
        yield pending, text + line.text
        pending = None
    if pending is not None:
        yield pending, text


def ogiflow_commands(text: str) -> list[list[str]]:
    """The argument lists of every ``ogiflow`` command in one shell line."""
    lexer = shlex.shlex(text, posix=True, punctuation_chars=";&|()")
    lexer.whitespace_split = True
    lexer.commenters = "#"
    tokens = list(lexer)
    commands: list[list[str]] = []
    start = True
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok in SHELL_OPERATORS:
            start = True
        elif start and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", tok):
            pass  # an environment assignment before the command word
        elif start:
            start = False
            if Path(tok).name == "ogiflow":
                j = i + 1
                while j < len(tokens) and tokens[j] not in SHELL_OPERATORS:
                    j += 1
                commands.append(tokens[i + 1:j])
                i = j
                continue
        i += 1
    return commands


def commands_or_error(text: str) -> list[list[str]] | str:
    """:func:`ogiflow_commands` of ``text``, or why the line cannot be read as shell."""
    try:
        return ogiflow_commands(text)
    except ValueError as exc:  # shlex: an unclosed quote
        if not re.search(r"(^|[\s;&|(])(\S*/)?ogiflow\s", text):
            return []  # not a command line at all (a diagram in an unlabelled block)
        return f"not a shell line ({exc}): {text.strip()}"


def shown_commands() -> Iterator[tuple[Line, list[str] | str, bool]]:
    """Every ``ogiflow`` command of the manual: (line, arguments or why they cannot be read,
    from an inline span)."""
    for page in PAGES:
        lines = page_lines(page)
        blocks: dict[tuple[str, int], list[Line]] = {}
        previous: Line | None = None
        block = 0
        for line in lines:
            if line.fence is None:
                for m in INLINE_CODE.finditer(line.text):
                    span = m.group(2).strip()
                    if re.match(r"^(\S*/)?ogiflow\s", span + " "):
                        found = commands_or_error(span)
                        for argv in [found] if isinstance(found, str) else found:
                            yield line, argv, True
            elif line.fence in SHELL_LANGUAGES:
                if previous is None or previous.fence is None or previous.number != line.number - 1:
                    block += 1
                blocks.setdefault((line.fence, block), []).append(line)
            previous = line
        for block_lines in blocks.values():
            for line, text in logical_lines(block_lines):
                found = commands_or_error(text)
                for argv in [found] if isinstance(found, str) else found:
                    yield line, argv, False


def names_a_command(argv: list[str]) -> bool | None:
    """True when ``argv`` is a path of command names of the parser, False when one is not a
    command, None when ``argv`` has more than command names (options, arguments)."""
    parser = build_parser()
    for i, word in enumerate(argv):
        subparsers = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        if word.startswith("-") or not subparsers:
            return None
        choices = subparsers[0].choices
        if word not in choices:
            return False if i == 0 or all(w in choices for w in argv[i:i + 1]) else None
        parser = choices[word]
    return True


def parse_problem(argv: list[str]) -> str | None:
    """The parser's complaint about ``argv``, or None when it accepts it (``--help`` too)."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code not in (0, None):
            lines = err.getvalue().strip().splitlines()
            return lines[-1] if lines else f"exit code {exc.code}"
    return None


def test_the_manual_has_its_pages() -> None:
    assert (ROOT / "README.md") in PAGES and len(PAGES) > 5


def test_every_relative_link_and_image_resolves() -> None:
    found = list(links())
    assert found, "no links found: the link pattern is broken"
    problems = [f"{line.where()}: {why}" for line, target in found
                if (why := link_problem(line, target)) is not None]
    assert not problems, "broken links:\n" + "\n".join(problems)


def test_every_ogiflow_command_shown_is_accepted_by_the_parser() -> None:
    shown = list(shown_commands())
    assert any(not inline for _, _, inline in shown), "no command in a code block found"
    problems: list[str] = []
    for line, argv, inline in shown:
        if isinstance(argv, str):
            problems.append(f"{line.where()}: {argv}")
            continue
        command = "ogiflow " + shlex.join(argv)
        if inline:
            named = names_a_command(argv)
            if named is True:
                continue
            if named is False:
                problems.append(f"{line.where()}: `{command}`: no such command")
                continue
        why = parse_problem(argv)
        if why is not None:
            problems.append(f"{line.where()}: `{command}`: {why}")
    assert not problems, "commands the parser refuses:\n" + "\n".join(problems)


@pytest.mark.parametrize("text, expected", [
    (".venv/bin/ogiflow run --duration 120", [["run", "--duration", "120"]]),
    ("tools/install.sh && .venv/bin/ogiflow run --duration 120", [["run", "--duration", "120"]]),
    ("XDG_CACHE_HOME=/tmp/c ogiflow bench  # a comment", [["bench"]]),
    ("journalctl -u ogiflow -f", []),
    ('ogiflow run --set "a.b=[[1, 2]]" | tee log', [["run", "--set", "a.b=[[1, 2]]"]]),
])
def test_commands_are_found_in_a_shell_line(text: str, expected: list[list[str]]) -> None:
    assert ogiflow_commands(text) == expected


def test_a_wrong_command_is_refused_with_the_parsers_message() -> None:
    assert parse_problem(["run", "--duration", "120"]) is None
    assert parse_problem(["run", "--help"]) is None
    assert "unrecognized arguments" in (parse_problem(["run", "--durations", "1"]) or "")
    assert names_a_command(["eval", "emission"]) is True
    assert names_a_command(["evaluate"]) is False
    assert names_a_command(["eval", "emission", "--data", "x"]) is None


def test_headings_give_githubs_anchors() -> None:
    assert slug("3. Gas absorption: gas cell, `ogiflow calibrate gascell`") == \
        "3-gas-absorption-gas-cell-ogiflow-calibrate-gascell"
    assert slug("Paper equations -> modules") == "paper-equations---modules"
