"""The README stays a document for users: short, free of development-process wording, and every
command and option it shows is one the tool has (each option checked against its command's
--help). Validation figures belong in docs/validation.md."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mocap_calib.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
MAX_LINES = 300

#: Options the README shows that --help does not list (yet to be added to their command);
#: test_pending_options_are_still_pending fails once one of them is in --help.
PENDING_OPTIONS: set[str] = set()

#: Development-process wording: history, bookkeeping and work-tracking words. Word boundaries
#: keep legitimate uses ("the run stops with exit 3", "does not stop the others") out.
PROCESS_WORDS = [
    r"(?<![\w&`])#\d+\b",                       # issue numbers
    r"\bissues?\b",
    r"\b(this|last|previous|earlier|next|each|every|one) stops?\b", r"\bstop \d+\b",
    r"\bsession \d+\b", r"\bround of work\b", r"\bthis work\b",
    r"\btargets?\b", r"\bmet\b", r"\bbar\b",
    r"\bnow\b", r"\bwas\b", r"\bwere\b", r"\bnot yet\b", r"\bno longer\b", r"\banymore\b",
    r"\bused to\b", r"\bpreviously\b", r"\bnewly\b", r"\(new\)", r"\bnew:",
    r"\bnew (option|command|reader|feature|flag)s?\b",
    r"\b(before|after|since) (the|this|that) (fix|change|commit|work|stop|issue)\b",
    r"\bcommit [0-9a-f]{7,}\b", r"\bwe (tried|changed|fixed|added|measured)\b",
    r"\b(TODO|FIXME|XXX|WIP)\b",
]


def _fenced_blocks(text: str) -> list[str]:
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)


def _commands_in(block: str) -> list[list[str]]:
    """Each `mocap-calib ...` command line of a code block, as tokens without the comment
    (continuation lines joined)."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        line = re.sub(r"\s#.*$", "", line).strip()
        if line.startswith("mocap-calib "):
            out.append(line.split())
    return out


def _help_options(name: str | None, capsys: pytest.CaptureFixture[str],
                  monkeypatch: pytest.MonkeyPatch) -> tuple[set[str], set[str]]:
    """(commands, options) that ``--help`` lists (the app's, or one command's)."""
    monkeypatch.setenv("COLUMNS", "250")
    capsys.readouterr()
    assert main([*([name] if name else []), "--help"]) == 0
    text = capsys.readouterr().out
    options, commands = set(), set()
    for line in text.splitlines():
        m = re.match(r"│(?: {1,4}|\s\*\s+)(-\S.*)$", line)  # an option row, not a wrapped line
        if m:
            for tok in m.group(1).split():
                if not tok.startswith("-"):
                    break
                options.add(tok)
        m = re.match(r"│ ([a-z][a-z-]*)\s{2,}\S", line)  # a command row of the app's help
        if m:
            commands.add(m.group(1))
    return commands, options


def test_readme_is_short() -> None:
    n = len(README.splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines; keep it under {MAX_LINES} (depth: docs/)"


@pytest.mark.parametrize("pattern", PROCESS_WORDS)
def test_readme_has_no_development_process_wording(pattern: str) -> None:
    hits = [f"line {k + 1}: {line.strip()}" for k, line in enumerate(README.splitlines())
            if re.search(pattern, line, flags=re.I if pattern.islower() else 0)]
    assert not hits, f"{pattern!r} in README.md (history and process go to git, figures to " \
                     f"docs/validation.md):\n" + "\n".join(hits)


def test_the_word_list_catches_what_it_is_for() -> None:
    """The patterns catch process wording and pass the legitimate phrases a user doc has."""
    def caught(s: str) -> bool:
        return any(re.search(p, s, flags=re.I if p.islower() else 0) for p in PROCESS_WORDS)

    for bad in ("see #26", "the issue's bar", "in this stop", "session 7 measured it",
                "the speed target", "every target met", "it now takes 3 s", "it was slower",
                "before the fix", "a new option (new)", "TODO: explain"):
        assert caught(bad), bad
    for good in ("the run stops with exit 3", "a failing session does not stop the others",
                 "a 90 s session", "`#timestamp [ns]`", "a new take", "the newest result",
                 "metres", "unmet", "stops at the first error", "the mocap stream",
                 "one line naming the file, the problem and the fix"):
        assert not caught(good), good


def test_links_to_docs_exist() -> None:
    for target in re.findall(r"\]\(([^)#]+)\)", README):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links to {target}, which does not exist"


def test_every_command_and_option_shown_exists(capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    commands, _ = _help_options(None, capsys, monkeypatch)
    assert {"calibrate", "diagnose", "batch"} <= commands, commands  # the parse works
    shown = [c for block in _fenced_blocks(README) for c in _commands_in(block)]
    assert len(shown) >= 20, "the README's code blocks show the commands"
    helps: dict[str, set[str]] = {}
    missing = []
    for tokens in shown:
        name = tokens[1]
        assert name in commands, f"`mocap-calib {name}` in README.md is not a command"
        if name not in helps:
            helps[name] = _help_options(name, capsys, monkeypatch)[1]
        assert {"--help"} <= helps[name], f"no options parsed from `{name} --help`"
        for tok in tokens[2:]:
            opt = tok.split("=")[0]
            if re.fullmatch(r"--[a-z][a-z0-9-]*", opt) and opt not in helps[name] \
                    and opt not in PENDING_OPTIONS:
                missing.append(f"mocap-calib {name} {opt}")
    assert not missing, "options shown in README.md that --help does not list: " + \
        ", ".join(missing)


def test_options_named_in_the_text_exist(capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """An option named in running text (`--foo`) is one some command has."""
    commands, _ = _help_options(None, capsys, monkeypatch)
    every = set().union(*(_help_options(c, capsys, monkeypatch)[1] for c in commands))
    prose = re.sub(r"^```.*?^```", "", README, flags=re.S | re.M)
    named = {m.split("=")[0] for span in re.findall(r"`([^`]+)`", prose)
             for m in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", span)}
    unknown = sorted(named - every - PENDING_OPTIONS)
    assert not unknown, f"README.md names options no command has: {unknown}"


def test_pending_options_are_still_pending(capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Fails once the pending options land in `calibrate --help`: then empty PENDING_OPTIONS
    so that the README's use of them is checked like every other option's."""
    landed = PENDING_OPTIONS & _help_options("calibrate", capsys, monkeypatch)[1]
    assert not landed, f"{sorted(landed)} are in `calibrate --help`: remove them from " \
                       "PENDING_OPTIONS in tests/test_readme.py"
