"""The canonical geometric subproblems of IK-Geo (Elias & Wen, "IK-Geo: Unified robot inverse
kinematics using subproblem decomposition", arXiv:2211.05737, 2022; Mechanism and Machine Theory
2024): the Paden-Kahan subproblems 1-4 (Paden 1986, after Kahan) and IK-Geo's 5 and 6, in
numpy, batched over leading axes. Each returns a :class:`SubproblemSolutions` (all solutions,
``valid`` slots, residuals, ``exact`` / ``ls`` and ``degenerate`` flags). docs/ik.md, section
"Subproblems", has the table; the tolerances are in ``derive.ik.tolerances`` (``SP_*``).
"""

from derive.ik.subproblems._common import SubproblemSolutions, rot
from derive.ik.subproblems.sp1 import sp1
from derive.ik.subproblems.sp2 import sp2
from derive.ik.subproblems.sp3 import sp3
from derive.ik.subproblems.sp4 import sp4
from derive.ik.subproblems.sp5 import sp5
from derive.ik.subproblems.sp6 import sp6

__all__ = ["SubproblemSolutions", "rot", "sp1", "sp2", "sp3", "sp4", "sp5", "sp6"]
