"""The thesis's printed appendices B, C and formulas 4.9-4.44 against the derivation.

docs/errata.md must list exactly the equations the comparison finds wrong.
"""

import re
from pathlib import Path

import pytest
from thesis_compare import check_formulas, compare_equations, load

#: one pytest-xdist worker runs the tests of group "ur-derivation" (make test: --dist loadgroup),
#: so the symbolic work they share (the UR family's equations, memoised in the process) is done once
pytestmark = pytest.mark.xdist_group("ur-derivation")

ERRATA = Path(__file__).resolve().parent.parent / "docs" / "errata.md"


@pytest.fixture(scope="module")
def comparison():
    return compare_equations()


def test_every_equation_is_transcribed():
    data = load()
    ids = [e["id"] for e in data["appendix"]]
    assert ids == [f"B.{k}" for k in range(1, 43)] + [f"C.{k}" for k in range(1, 22)]


def test_comparison_results(comparison):
    verdicts = {entry["id"]: v for entry, _, v in comparison}
    wrong = sorted((k for k, v in verdicts.items() if v == "wrong"), key=lambda s: (s[0], float(s[2:])))
    assert wrong == ["B.3", "B.17", "B.18", "B.36", "B.37", "B.38", "B.39", "B.41"]
    assert [k for k, v in verdicts.items() if v == "not legible"] == ["B.2"]
    assert sum(v == "correct" for v in verdicts.values()) == 54 + 12


def test_errata_file_lists_exactly_the_wrong_equations(comparison):
    text = ERRATA.read_text()
    section = text.split("### Appendices B and C")[1].split("\n## ")[0]
    listed = re.findall(r"^\| (B\.\d+|C\.\d+) \|", section, flags=re.M)
    wrong = [entry["id"] for entry, _, v in comparison if v == "wrong"]
    assert sorted(listed) == sorted(wrong)


def test_closed_forms_contain_the_true_angle():
    for entry, fraction in check_formulas(samples=100):
        assert fraction == 1.0, entry["id"]
