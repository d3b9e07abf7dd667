"""The C twin of the subproblem library: ``templates/subproblems.h.j2`` rendered with the
tolerances of ``derive.ik.tolerances`` (sp1-sp6 of ``derive.ik.subproblems``, header only)."""

from __future__ import annotations

from derive._version import __version__
from derive.codegen.templates import template_environment
from derive.ik.tolerances import SP_EXACT_TOL, SP_FREE_ANGLE, SP_RANK_TOL, SP_ROOT_MODULUS


def subproblems_header() -> str:
    """C99 (and C++) header with ``dq_sp1`` .. ``dq_sp6``: the numpy functions' formulas, flags
    (``DQ_SP_EXACT``, ``DQ_SP_DEGENERATE``) and residuals, for one instance per call."""
    return template_environment().get_template("subproblems.h.j2").render(
        version=__version__, exact_tol=repr(SP_EXACT_TOL), free_angle=repr(SP_FREE_ANGLE),
        rank_tol=repr(SP_RANK_TOL), root_modulus=repr(SP_ROOT_MODULUS))
