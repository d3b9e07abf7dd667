"""The documentation site and its examples (docs/contributing.md).

* the site builds with ``mkdocs build --strict`` (warnings are errors), without network;
* every code block marked runnable (a ``<!-- run -->`` line right before its fence) runs: the
  marked Python blocks of one page are joined into one script, in page order, and run in a fresh
  process in an empty temporary folder (blocks of a page share their state);
* every Python block of the tutorial and of Getting started is marked;
* the C program of Getting started (``main.c`` and ``Makefile`` blocks, the shipped
  ``generated/ur5/ur5_kinematics.{c,h}`` copied next to them) builds with make and prints the
  page's ``output`` block;
* the convention figures of docs/img are what ``derive.reports.diagrams`` draws.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from derive.reports import diagrams

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RUN_MARK = "<!-- run -->"
# a fenced block: its opening fence (``` and an info string), its body, its closing fence
FENCE = re.compile(r"^(?P<indent>[ ]*)(?P<fence>`{3,})(?P<info>[^\n`]*)\n(?P<body>.*?)^(?P=indent)(?P=fence)[ ]*$",
                   re.S | re.M)


def blocks(path: Path) -> list[dict]:
    """The fenced code blocks of a Markdown page: language, title, body, and whether the line
    before the fence is the run marker."""
    text = path.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        info = m.group("info").strip()
        lang = info.split()[0] if info else ""
        title = re.search(r'title="([^"]*)"', info)
        before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        out.append({"lang": lang, "title": title.group(1) if title else None, "body": m.group("body"),
                    "run": before == RUN_MARK, "line": text.count("\n", 0, m.start()) + 1})
    return out


def runnable_pages() -> list[Path]:
    pages = sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]
    return [p for p in pages if any(b["run"] for b in blocks(p))]


def test_readme_opens_with_title_paragraph_and_the_two_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    parts = text.split("\n\n")
    assert parts[0] == "# dq-derive"
    assert "robot" in parts[1] and not parts[1].startswith(("#", " "))       # one paragraph: what, for whom
    marker, *commands = parts[2].splitlines()            # the shell examples' norun marker, then the block
    assert marker.startswith("<!-- norun: ")
    assert [line.split("#")[0].strip() for line in commands] == ["make generate", "make test"]


def test_the_parser_sees_marked_blocks_and_titles():
    page = blocks(DOCS / "getting-started.md")
    assert any(b["run"] and b["lang"] == "python" for b in page)
    assert {"main.c", "Makefile", "output"} <= {b["title"] for b in page}


@pytest.mark.parametrize("page", ["getting-started.md", "tutorial.md"])
def test_every_python_block_is_marked(page):
    unmarked = [b["line"] for b in blocks(DOCS / page) if b["lang"] in ("python", "py") and not b["run"]]
    assert unmarked == [], f"{page}: Python blocks without {RUN_MARK} at lines {unmarked}"


@pytest.mark.parametrize("page", runnable_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_marked_blocks_run(page, tmp_path):
    marked = [b for b in blocks(page) if b["run"]]
    assert all(b["lang"] in ("python", "py") for b in marked), "only Python blocks are run"
    script = "\n\n".join(f"# --- {page.name}, line {b['line']}\n{b['body']}" for b in marked)
    (tmp_path / "page.py").write_text(script, encoding="utf-8")
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")
    r = subprocess.run([sys.executable, "page.py"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, f"{page.name}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"


@pytest.mark.skipif(shutil.which("make") is None or shutil.which("gcc") is None, reason="needs make and gcc")
def test_getting_started_c_program(tmp_path):
    page = {b["title"]: b["body"] for b in blocks(DOCS / "getting-started.md") if b["title"]}
    for name in ("ur5_kinematics.c", "ur5_kinematics.h"):
        shutil.copy(ROOT / "generated" / "ur5" / name, tmp_path / name)
    (tmp_path / "main.c").write_text(page["main.c"], encoding="utf-8")
    (tmp_path / "Makefile").write_text(page["Makefile"], encoding="utf-8")
    assert "\n\t" in page["Makefile"], "the Makefile's recipe lines need a tab"
    subprocess.run(["make"], cwd=tmp_path, check=True, capture_output=True, text=True, timeout=120)
    r = subprocess.run(["./main"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout == page["output"]


def test_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    pytest.importorskip("mkdocstrings_handlers.python")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                        "--config-file", str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-5000:] + r.stderr[-5000:]
    site = tmp_path / "site"
    for page in ("index.html", "getting-started.html", "tutorial.html", "concepts.html", "cli.html",
                 "api/reference.html", "appendix-ur3.html"):
        assert (site / page).is_file(), page
    assert (site / "img" / "dh.png").is_file()
    # the API reference holds the docstrings, the appendix page the generated equations
    assert "from_position_quaternion" in (site / "api" / "pose.html").read_text(encoding="utf-8")
    assert "B.42" in (site / "appendix-ur3.html").read_text(encoding="utf-8")
    # nothing is fetched from elsewhere when a page is read, apart from MathJax for the equations
    html = (site / "index.html").read_text(encoding="utf-8")
    assert "fonts.googleapis.com" not in html


def test_convention_figures_are_drawn_by_the_code(tmp_path):
    poses = diagrams.frames_figure(tmp_path / "frames.png")
    # the frames drawn are the matrices written by hand: Q_02 = Q_01 Q_12 composes like them
    c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
    m01 = np.array([[c, -s, 0, 1.0], [s, c, 0, 0.4], [0, 0, 1, 0.5], [0, 0, 0, 1]])   # Rot(z, 60 deg)
    m12 = np.array([[1, 0, 0, 0.9], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])      # Rot(x, -90 deg)
    assert np.allclose(poses["1"], m01, atol=1e-12)
    assert np.allclose(poses["2"], m01 @ m12, atol=1e-12)
    dh = diagrams.dh_figure(tmp_path / "dh.png", theta=0.9, d=0.7, a=1.1, alpha=0.8)
    c, s, ca, sa = np.cos(0.9), np.sin(0.9), np.cos(0.8), np.sin(0.8)
    expected = np.array([[c, -s * ca, s * sa, 1.1 * c], [s, c * ca, -c * sa, 1.1 * s],
                         [0, sa, ca, 0.7], [0, 0, 0, 1]])          # the textbook standard-DH matrix
    assert np.allclose(dh["i"], expected, atol=1e-12)
    for name in ("frames.png", "dh.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (DOCS / "img" / name).is_file(), f"docs/img/{name}: run make figures"
