"""Every shell example of README.md and docs/ runs (issue 35; docs/contributing.md).

Which blocks are shell examples:

* fenced blocks of language ``sh``, ``bash``, ``shell``, ``console`` or ``shell-session``;
* unlabeled or ``text`` blocks with ``$ `` lines (a transcript: the ``$ `` line is the command,
  the lines below it, up to the next ``$ `` line, its output);
* unlabeled fenced blocks and indented code blocks whose first line is a command
  (``dq-derive``, ``python -m derive``, ``make``, ``pip``, ``cp``, ...).

Each command line is one of

* a synopsis: ``dq-derive`` with usage syntax (``[``, ``|``, ``...`` or an upper-case
  placeholder such as ``ROBOT`` or ``FILE``): not run, but its subcommand and every option it
  names must exist in the parser;
* a ``dq-derive`` / ``python -m derive`` command: run in one temporary folder per test process
  (shared by the pages it runs), a page's commands in page order, so the files one command
  writes are there for the next; ``path/to/...``
  placeholders are replaced by real files (:data:`PLACEHOLDERS`, the one place that maps them),
  and ``docs/examples/...`` by the repository's example files (:data:`EXAMPLES`).
  A plain command runs in this process through ``derive.cli.main`` (the function the console
  script calls: no 2 s start-up per command); one with shell syntax (``; echo $?``, a pipe, a
  redirection) runs in bash with the venv's ``bin`` first on ``PATH``, so through the console
  script itself. Checked: exit code 0; no ``dq-derive:`` error, warning or deprecation note on
  stderr; the output shown in the page (``...`` skips lines or, inside a line, text; numbers
  agree to one unit of their last printed digit, residuals printed below 1e-9 only need to stay
  below it, and a time in s or ms may be anything); without shown output, the key part of the
  output of the subcommand (:data:`KEY`), or valid JSON with ``--json``; every file named by
  ``--out``, ``--urdf``, ``--yaml`` or ``--plot`` written (a PNG with its signature);
* ``cat FILE`` with the file's contents below it: FILE (an example file of the repository or
  one an earlier command wrote) must hold what the page shows (:func:`check_cat`);
* anything else (``make``, ``pip``, ``cp``, ``./main``, ...): the block needs a marker on the
  line right before it, ``<!-- norun: WHY -->``, naming why it is not run (and where it is
  tested instead). A block without the marker that holds such a line fails.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shlex
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from derive.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
SHELL_LANGS = {"sh", "bash", "shell", "console", "shell-session"}
NORUN = re.compile(r"^<!--\s*norun:\s*(?P<why>\S.*?)\s*-->$")
FENCE = re.compile(r"^(?P<indent>[ ]*)(?P<fence>`{3,})(?P<info>[^\n`]*)\n(?P<body>.*?)^(?P=indent)(?P=fence)[ ]*$",
                   re.S | re.M)
#: The first word of a line that is a shell command (an unlabeled block that starts with one is
#: a shell example).
COMMAND = re.compile(r"^(\$ |dq-derive\b|python3? |\.venv/|make\b|pip3?\b|cp |mkdir |cd |rm |xacro\b|git |"
                     r"mkdocs\b|\./)")
#: Usage syntax: the line is a synopsis, not a command.
SYNOPSIS = re.compile(r"\[|\||\.\.\.|(?<![\w/.-])[A-Z][A-Z0-9_]+(?![\w-])")
SHELL_SYNTAX = re.compile(r"[;|&<>`]|\$\(|\$\?")
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _example_robot_data(rel: str) -> Path:
    for base in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        path = Path(base) / "cmeel.prefix" / "share" / "example-robot-data" / "robots" / rel
        if path.is_file():
            return path
    pytest.fail("example-robot-data is not installed: `pip install -e '.[test]'` installs it")


#: The one place where the docs' ``path/to/...`` placeholders get real files.
PLACEHOLDERS = {
    "path/to/ur5_robot.urdf": lambda: _example_robot_data("ur_description/urdf/ur5_robot.urdf"),
}

#: Example files of the repository that pages name by their path from its root (the commands run
#: in a temporary folder): ``docs/examples/...`` becomes the absolute path.
EXAMPLES = re.compile(r"(?<![\w/.])docs/examples/[\w./-]+")

#: The key part of a subcommand's output, checked where the page shows none.
KEY = {"robots": "closed-form IK", "fk": "position (m):", "ik": "solution", "refine": "seed(s)",
       "classify": "class:", "export": "wrote ", "plot": "wrote ", "appendix": "wrote ",
       "kernels": "wrote "}


# --------------------------------------------------------------------------- #
# Reading the pages
# --------------------------------------------------------------------------- #
def _before(text: str, start: int) -> str:
    """The nearest non-blank line before offset ``start``."""
    lines = [line for line in text[:start].splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def shell_blocks(path: Path) -> list[dict]:
    """The shell examples of a page: line, language, the lines, and the norun reason (or None)."""
    text = path.read_text(encoding="utf-8")
    out, spans = [], []
    for m in FENCE.finditer(text):
        spans.append((m.start(), m.end()))
        info = m.group("info").strip()
        lang = info.split()[0] if info else ""
        lines = [line[len(m.group("indent")):] for line in m.group("body").splitlines()]
        first = next((line for line in lines if line.strip()), "")
        transcript = any(line.startswith("$ ") for line in lines)
        if lang in SHELL_LANGS or (lang in ("", "text") and transcript) or (lang == "" and COMMAND.match(first)):
            out.append({"start": m.start(), "lang": lang, "lines": lines, "before": _before(text, m.start())})
    # indented code blocks (four spaces, after a blank line) that start with a command
    offset, lines = 0, text.splitlines(keepends=True)
    i = 0
    while i < len(lines):
        start = offset
        inside = any(a <= start < b for a, b in spans)
        if (not inside and lines[i].startswith("    ") and COMMAND.match(lines[i][4:])
                and (i == 0 or not lines[i - 1].strip() or NORUN.match(lines[i - 1].strip()))):
            body = []
            while i < len(lines) and (lines[i].startswith("    ") or not lines[i].strip()):
                body.append(lines[i][4:].rstrip("\n"))
                offset += len(lines[i])
                i += 1
            out.append({"start": start, "lang": "", "lines": body, "before": _before(text, start)})
            continue
        offset += len(lines[i])
        i += 1
    for b in out:
        b["line"] = text.count("\n", 0, b["start"]) + 1
        mark = NORUN.match(b["before"])
        b["norun"] = mark.group("why") if mark else None
    return sorted(out, key=lambda b: b["start"])


def commands(block: dict) -> list[tuple[str, list[str] | None]]:
    """(command line, shown output lines or None) of a block: a transcript's ``$ `` lines with
    the lines below them, or every line of a script (comments, blank lines and continuation
    backslashes and indented continuation lines handled)."""
    lines = [line.rstrip() for line in block["lines"]]
    if any(line.startswith("$ ") for line in lines):
        out = []
        for line in lines:
            if line.startswith("$ "):
                out.append([line[2:], []])
            elif out:
                out[-1][1].append(line)
        return [(c, [x for x in shown if x.strip()] or None) for c, shown in out]
    out, pending = [], ""
    for line in lines:
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        if line[:1].isspace() and out and not pending:      # a synopsis wrapped onto the next line
            out[-1] = (out[-1][0] + " " + line.strip(), None)
            continue
        out.append((pending + line, None))
        pending = ""
    return out


def _argv(command: str) -> list[str] | None:
    """The arguments after ``dq-derive`` / ``python -m derive`` (None for another command)."""
    words = shlex.split(command, comments=True)
    if words[:1] == ["dq-derive"]:
        return words[1:]
    if words[:3] in (["python", "-m", "derive"], ["python3", "-m", "derive"]):
        return words[3:]
    return None


def _code(command: str) -> str:
    """The command without its trailing comment (a # that starts a word, outside quotes)."""
    quote = None
    for pos, ch in enumerate(command):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (pos == 0 or command[pos - 1].isspace()):
            return command[:pos].rstrip()
    return command.rstrip()


def _subparsers(parser):
    [action] = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
    return action.choices


# --------------------------------------------------------------------------- #
# Comparing with the shown output
# --------------------------------------------------------------------------- #
def _line_pattern(expected: str) -> tuple[re.Pattern, list[tuple[str, bool]]]:
    """A regex for one shown line (numbers captured, whitespace runs flexible, ``...`` any
    text) and, per captured number, (its text, whether it is a time)."""
    parts, numbers = [], []
    pos = 0
    token = re.compile(rf"\.\.\.|\s+|(?<![\w.]){NUMBER}(?![\w.])")
    for m in token.finditer(expected):
        parts.append(re.escape(expected[pos:m.start()]))
        t = m.group(0)
        if t == "...":
            parts.append(".*?")
        elif t.isspace():
            parts.append(r"\s+")
        else:
            parts.append(f"({NUMBER})")
            numbers.append((t, bool(re.match(r"\s*m?s\b", expected[m.end():]))))
        pos = m.end()
    parts.append(re.escape(expected[pos:]))
    return re.compile(r"\s*" + "".join(parts) + r"\s*"), numbers


def _number_ok(shown: str, got: str, is_time: bool) -> bool:
    if is_time:
        return True
    e, a = float(shown), float(got)
    if "e" in shown.lower() and abs(e) < 1e-9:
        return abs(a) < 1e-9
    digits = shown.lower().split("e")[0]
    decimals = len(digits.split(".")[1]) if "." in digits else 0
    scale = 10.0 ** (int(shown.lower().split("e")[1]) if "e" in shown.lower() else 0)
    return abs(a - e) <= 10.0 ** -decimals * scale * 1.0000001


def _line_ok(expected: str, actual: str) -> bool:
    pattern, numbers = _line_pattern(expected)
    m = pattern.fullmatch(actual)
    return bool(m) and all(_number_ok(s, g, t) for (s, t), g in zip(numbers, m.groups()))


def compare(shown: list[str], output: str) -> str:
    """'' when ``output`` is the shown transcript (first line to last; a line ``...`` skips
    any number of lines), else what differs."""
    actual = [line.rstrip() for line in output.splitlines() if line.strip()]
    i, skip = 0, False
    for k, line in enumerate(shown):
        if line.strip() == "...":
            skip = True
            continue
        j = i
        while j < len(actual) and not _line_ok(line, actual[j]):
            if not skip:
                break
            j += 1
        if j >= len(actual) or not _line_ok(line, actual[j]):
            return f"shown line {k + 1} {line.strip()!r} not found (at output line {i + 1}: " \
                   f"{actual[i] if i < len(actual) else '<end>'!r})"
        i, skip = j + 1, False
    if not skip and i < len(actual):
        return f"the output goes on after the shown lines: {actual[i]!r}"
    return ""


# --------------------------------------------------------------------------- #
# Running
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """One folder for every page's commands (pages in order, so files persist)."""
    return tmp_path_factory.mktemp("doc-shell")


def _map(command: str) -> str:
    for placeholder, target in PLACEHOLDERS.items():
        if placeholder in command:
            command = command.replace(placeholder, shlex.quote(str(target())))
    command = EXAMPLES.sub(lambda m: shlex.quote(str(ROOT / m.group(0))), command)
    left = re.findall(r"path/to/\S+", command)
    assert not left, f"placeholder(s) {left} not mapped: add them to PLACEHOLDERS"
    return command


def _run_inprocess(argv: list[str], cwd: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    old = Path.cwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:              # argparse: a usage error
                code = exc.code if isinstance(exc.code, int) else 2
    finally:
        os.chdir(old)
    return code, out.getvalue(), err.getvalue()


def _run_bash(command: str, cwd: Path) -> tuple[int, str, str]:
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               MPLBACKEND="Agg")
    # stderr into stdout, in the order printed: a page shows a transcript of the terminal
    r = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=300)
    return r.returncode, r.stdout, ""


def _written(argv: list[str]) -> list[str]:
    out = []
    for opt in ("--out", "--urdf", "--yaml", "--plot"):
        if opt in argv[:-1]:
            out.append(argv[argv.index(opt) + 1])
    return out


def check_synopsis(command: str) -> str:
    """'' when the subcommand and every option a synopsis names exist, else what is wrong."""
    words = _code(command).split()
    words = words[1:] if words[0] == "dq-derive" else words[3:]
    if not words or words[0].startswith("-"):
        return ""
    subs = _subparsers(build_parser())
    if words[0] not in subs:
        return f"synopsis {command!r}: no subcommand {words[0]!r}"
    known = {o for a in subs[words[0]]._actions for o in a.option_strings}
    named = set(re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", " ".join(words[1:])))
    unknown = sorted(named - known)
    return f"synopsis {command!r}: {words[0]} has no option(s) {unknown}" if unknown else ""


CAT = re.compile(r"^cat (\S+)$")


def check_cat(command: str, shown: list[str] | None, cwd: Path) -> str:
    """``cat FILE`` in a transcript: the page shows the file, which must hold what is shown (a
    file of the repository, ``docs/examples/...``, or one an earlier command of the page wrote
    into the folder); '' when it does."""
    name = shlex.split(_map(CAT.match(_code(command)).group(1)))[0]
    path = Path(name) if Path(name).is_absolute() else cwd / name
    if not path.is_file():
        return f"`{command}`: {name} does not exist (neither in the repository nor written by an earlier command)"
    if shown is None:
        return f"`{command}`: the page shows no content of {name}"
    diff = compare(shown, path.read_text(encoding="utf-8"))
    return f"`{command}`: {diff}" if diff else ""


def run_command(command: str, shown: list[str] | None, cwd: Path) -> str:
    """Run one doc command; '' when it runs as the page says, else what went wrong."""
    code_text = _map(_code(command))
    argv = _argv(code_text)
    if SHELL_SYNTAX.search(code_text):
        code, out, err = _run_bash(code_text, cwd)
        argv = _argv(re.split(r"[;|&<>]", code_text)[0]) or []
    else:
        code, out, err = _run_inprocess(argv, cwd)
    where = f"`{command}`"
    if code != 0:
        return f"{where}: exit code {code}\n{out[-2000:]}\n{err[-2000:]}"
    notes = [line for line in err.splitlines() if line.startswith("dq-derive")]
    if SHELL_SYNTAX.search(code_text):
        # stderr is merged into the output there: a message of ours is fine only where the page
        # shows it
        notes = [line for line in out.splitlines()
                 if line.startswith("dq-derive: ") and line.strip() not in [x.strip() for x in shown or []]]
    if notes:
        return f"{where}: {notes}"
    if shown is not None:
        diff = compare(shown, out)
        if diff:
            return f"{where}: {diff}\n--- output:\n{out}"
    elif "--json" in argv:
        try:
            data = json.loads(out)
        except ValueError:
            return f"{where}: --json printed no JSON:\n{out[:2000]}"
        if not isinstance(data, dict) or not data:
            return f"{where}: --json printed {out[:200]!r}"
    elif argv and argv[0] in KEY and KEY[argv[0]] not in out:
        return f"{where}: {KEY[argv[0]]!r} not in the output:\n{out[-2000:]}"
    elif not out.strip():
        return f"{where}: printed nothing"
    for name in _written(argv):
        path = cwd / name
        if not (path.exists() and (path.is_dir() or path.stat().st_size > 0)):
            return f"{where}: {name} not written"
        if name.endswith(".png") and path.read_bytes()[:8] != b"\x89PNG\r\n\x1a\n":
            return f"{where}: {name} is not a PNG"
    return ""


def _kind(command: str) -> str:
    code = _code(command)
    if _argv(code) is None:
        return "other"
    return "synopsis" if SYNOPSIS.search(code.split(maxsplit=1)[1] if " " in code else "") else "run"


# --------------------------------------------------------------------------- #
# Tests
# --------------------------------------------------------------------------- #
def test_the_reader_finds_the_examples():
    found = {p.name: shell_blocks(p) for p in PAGES}
    readme = found["README.md"]
    assert readme and readme[0]["lines"][0].startswith("make generate") and readme[0]["norun"]
    cli = [c for b in found["cli.md"] for c in commands(b)]
    fk = next((c, s) for c, s in cli if c.startswith("dq-derive fk ur5 --q"))
    assert fk[1] and fk[1][0] == "ur5: end frame 'flange' at"
    assert _kind("dq-derive fk ROBOT --q Q [Q ...]") == "synopsis"
    assert _kind("dq-derive plot ur5 --q 20 -60 80 --deg --out ur5.png") == "run"
    assert _kind("make docs") == "other"
    assert _code('dq-derive robots   # the library') == "dq-derive robots"


def test_compare_is_strict():
    shown = ["ur5: target x", "  1   0.50000   -2.00000", "...", "done in 3.5 ms", "  2  1.0e-16"]
    good = "ur5: target x\n  1   0.50001   -2.00000\nmore\nlines\ndone in 812.0 ms\n  2  3.3e-14\n"
    assert compare(shown, good) == ""
    assert compare(shown, good.replace("0.50001", "0.50003"))              # beyond one unit
    assert compare(shown, good.replace("3.3e-14", "2.0e-03"))              # not a residual any more
    assert compare(shown, good + "extra\n")                                 # output goes on
    assert compare(shown, "x\n" + good)                                     # the first line is anchored


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_shell_example_runs(page, folder):
    problems = []
    for block in shell_blocks(page):
        where = f"{page.relative_to(ROOT)}:{block['line']}"
        cmds = commands(block)
        if block["norun"]:
            continue
        for command, shown in cmds:
            kind = _kind(command)
            if CAT.match(_code(command)):
                msg = check_cat(command, shown, folder)
                if msg:
                    problems.append(f"{where}: {msg}")
            elif kind == "other":
                problems.append(f"{where}: `{command}` cannot be run by the test: mark the block with "
                                "<!-- norun: WHY --> on the line before it")
            elif kind == "synopsis":
                msg = check_synopsis(command)
                if msg:
                    problems.append(f"{where}: {msg}")
            else:
                msg = run_command(command, shown, folder)
                if msg:
                    problems.append(f"{where}: {msg}")
    assert not problems, "\n\n".join(problems)


def test_the_console_script_and_python_m_derive_run_a_doc_command(folder):
    """The in-process runs above call derive.cli.main; the installed entry points print the same."""
    argv = ["fk", "ur5", "--q", "10", "-60", "80", "-20", "45", "30", "--deg"]
    code, out, _ = _run_inprocess(argv, folder)
    assert code == 0 and "position (m):" in out
    bin_dir = Path(sys.executable).parent
    for cmd in ([str(bin_dir / "dq-derive"), *argv], [sys.executable, "-m", "derive", *argv]):
        r = subprocess.run(cmd, cwd=folder, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert r.stdout == out
