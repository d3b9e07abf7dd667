"""The constants moved into derive.ik.tolerances (issue 31's leftovers): the general 6R's Newton
thresholds, the sp6 program's block test, the roots4 line's thresholds and the near-class kernels'
polish tolerances are defined there once, the modules that use them import them, the roots4
templates print them from there (no literal left), and the printed text is the literal the
templates had (the emitted kernels' bytes unchanged)."""

import inspect
import re
from pathlib import Path

import pytest

from derive.codegen import emit, polish
from derive.ik import general6r, program_parallel3, tolerances

TEMPLATES = Path(__file__).resolve().parents[1] / "templates"
MOVED = ["G6_NEWTON_STOP", "G6_NEWTON_DONE", "SP6_BLOCK_MIN", "ROOTS4_LEAD", "ROOTS4_DK_STOP",
         "ROOTS4_BIQUADRATIC", "ROOTS4_NEWTON_DF", "ROOTS4_NEWTON_STEP", "POLISH_STOP", "POLISH_ACCEPT",
         "POLISH_LAST_STEP", "SEED_KEEP"]


def test_defined_once_in_tolerances_and_imported():
    for name in MOVED:
        assert isinstance(getattr(tolerances, name), float), name
    for mod in (general6r, program_parallel3, polish, emit):
        src = inspect.getsource(mod)
        for name in MOVED:
            assert f"\n{name} = " not in src, f"{mod.__name__} redefines {name}"
    assert general6r.NEWTON_DONE is tolerances.G6_NEWTON_DONE == 1e-7
    assert program_parallel3.SP6_BLOCK_MIN is tolerances.SP6_BLOCK_MIN == 1e-6
    assert polish.POLISH_ACCEPT is tolerances.POLISH_ACCEPT == 1e-11
    assert polish.SEED_KEEP == tolerances.SEED_REACH + 1.0 == 5.0


@pytest.mark.parametrize("name", ["roots4.c.j2", "roots4.py.j2", "roots4_numpy.py.j2"])
def test_roots4_templates_print_the_tolerances(name):
    text = (TEMPLATES / name).read_text()
    assert not re.search(r"(?<![\w.])1e-(3|8|12|14)(?![\d])", text), name
    assert "ik.roots4.lead" in text and "ik.roots4.newton_df" in text and "ik.roots4.newton_step" in text


def test_printed_literals_are_the_old_ones():
    assert [emit._power_literal(x) for x in (1e-12, 1e-14, 1e-8, 1e-3)] == ["1e-12", "1e-14", "1e-8", "1e-3"]
    with pytest.raises(ValueError):
        emit._power_literal(1.5e-3)
