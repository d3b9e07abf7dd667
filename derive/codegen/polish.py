"""Near-class kernels: the closed form of a nominal robot, polished by Newton steps on the arm's
own FK (issue 30, item 3, emitted side).

A near-class arm R (a URDF's printed constants, decimal DH such as ``alpha: 1.5708``, a
calibrated arm) is a little off an exact robot N of a class with a closed form; the relation is
a :class:`derive.ik.nearclass.Nominal`, FK_R(q) ~= B FK_N(s q + o) T. The kernels of R then

1. move the pose into N's frames (B^-1 P T^-1) and run N's IK program
   (:func:`derive.ik.program.ik_program`; :func:`nominal_program` here), each candidate mapped
   back by q = s (q_N - o);
2. polish every candidate by damped Newton steps (Levenberg-Marquardt with the damping
   mu = |e|^2 of Yamashita and Fukushima, 2001, which keeps Newton's quadratic convergence) on
   R's exact FK in product-of-exponentials form (Lynch and Park, *Modern Robotics*, eq. 4.14:
   FK(q) = exp([S_1] q_1) ... exp([S_n] q_n) M, with S_i the joint screws at q = 0 from
   :func:`derive.model.geometry.numeric_chain`) and its analytic geometric (space-frame)
   Jacobian, columns [z_i x (p_end - c_i); z_i] for a revolute joint through c_i with direction
   z_i (eq. 5.11 written for the end point), [z_i; 0] for a prismatic one; the error
   e = (t_pose - t, vee(R_pose R^T)) and the step (J^T J + mu I) dq = J^T e solved by a 6x6
   Cholesky factorisation with guarded pivots; a step is clipped to :data:`POLISH_MAX_STEP` rad
   in its largest joint, so every value stays finite;
3. keep a candidate only when its residual (:data:`RESIDUAL_METRIC`: the larger of the position
   error in m and the rotation angle in rad between the emitted FK of the solution and the pose,
   as :func:`derive.kinematics.fk.pose_error`) is at most :data:`POLISH_ACCEPT` after at most
   :data:`POLISH_MAX_ITER` steps; near-duplicates (within the merge tolerance in every joint) are
   merged as for every kernel.

:func:`polish_context` gives the emitters (:func:`derive.codegen.emit.render_kernels` with
``nominal=``) the product-of-exponentials code and the constants.
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp

from derive.algebra import dualquat as dq
from derive.algebra.quaternion import dual_hamilton
from derive.codegen.formats import nominal_key
from derive.errors import DeriveError
from derive.ik.ir import IKProgram, Op, pos
from derive.ik.nearclass import Nominal
from derive.ik.program import ik_program
from derive.ik.tolerances import (POLISH_ACCEPT, POLISH_LAST_STEP, POLISH_STOP, REACH_TOL, SEED_KEEP,
                                  SEED_REACH, SEED_SINGULAR)
from derive.kinematics.fk import fk_matrix
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: The most Newton steps per candidate. (The tolerances POLISH_STOP, POLISH_ACCEPT,
#: POLISH_LAST_STEP and SEED_KEEP are in derive.ik.tolerances.)
POLISH_MAX_ITER = 30
#: The largest change of one joint in one Newton step (rad or m); longer steps are scaled down.
POLISH_MAX_STEP = 0.5
#: Newton steps the C kernels take for every candidate of a block at once, vectorised over the
#: block's poses (no early exit), before the residual decides which candidates go on one at a
#: time: two steps take a mismatch of 1e-5 (decimal DH, a URDF's printed constants) to rounding.
POLISH_VEC_STEPS = 2
#: The offsets t (in units of r = sqrt(deviation), rad) of the seeds q + t v along the singular
#: direction v of a candidate near a singular set (as derive.ik.nearclass._singular_seeds: the
#: two roots of a fold part as the square root of the offset) ...
SEED_FOLD = (1.0, -1.0, 3.0, -3.0)
#: ... and the offsets (rad) that do not scale with it (a joint pair that is nearly free).
SEED_TURN = (math.pi / 4, -math.pi / 4, math.pi / 2, -math.pi / 2, 3 * math.pi / 4, -3 * math.pi / 4, math.pi)
#: The most Newton steps of a seed near a singular set (a seed that leads to a root gets there in a
#: few; most lead nowhere, and their steps were most of the seeds' cost).
SEED_MAX_ITER = 20
#: Cyclic Jacobi sweeps at most for the eigenvalues of J^T J of a candidate the cheap bound marks
#: (:func:`seed_context`); a sweep stops the iteration when every off-diagonal entry is at most
#: 1e-30 of the trace.
SEED_JACOBI_SWEEPS = 12
#: The output width of near-class kernels with six joints to solve (a general 6R has at most 16
#: solutions, Raghavan and Roth); other arms get :data:`POLISH_EXTRA_SLOTS` slots past the nominal's
#: branches. The nominal's branches keep their slots; a seed's solution takes an extra slot.
POLISH_WIDTH_6R = 16
POLISH_EXTRA_SLOTS = 8
#: The one metric of the residual each solution reports.
RESIDUAL_METRIC = ("max(|t_fk - t_pose| (m), rotation angle between fk and pose (rad)), fk the "
                   "kernels' own fk of the solution")


def polish_width(branches: int, free_joints: int) -> int:
    """The most solutions near-class kernels return per pose: the nominal's ``branches`` slots (its
    candidates, polished) and extra slots for the solutions the seeds near singular sets find
    (a near-class arm is a general arm and may have more solutions than its nominal): 16 for six
    joints to solve (:data:`POLISH_WIDTH_6R`, at least ``branches``), else ``branches`` +
    :data:`POLISH_EXTRA_SLOTS`."""
    if free_joints == 6:
        return max(int(branches), POLISH_WIDTH_6R)
    return int(branches) + POLISH_EXTRA_SLOTS


def _number(x: float):
    x = float(x)
    return sp.Integer(int(x)) if x.is_integer() else sp.Float(x, 17)


def check_nominal(robot, nominal: Nominal) -> None:
    """DeriveError unless ``nominal`` fits ``robot`` (same number of joint variables, shapes of the
    relation, a unit B and T)."""
    if not isinstance(nominal, Nominal):
        raise DeriveError(f"nominal: expected a derive.ik.nearclass.Nominal, got {type(nominal).__name__}")
    if nominal.robot.dof != robot.dof:
        raise DeriveError(f"{robot.name}: the nominal robot {nominal.robot.name} has {nominal.robot.dof} "
                          f"joints, the arm {robot.dof}")
    for name, arr, n in (("base", nominal.base, 8), ("tool", nominal.tool, 8),
                         ("signs", nominal.signs, robot.dof), ("offsets", nominal.offsets, robot.dof)):
        a = np.asarray(arr, dtype=float)
        if a.shape != (n,) or not np.all(np.isfinite(a)):
            raise DeriveError(f"nominal.{name}: expected {n} finite numbers, got shape {a.shape}")
    if not np.all(np.abs(np.abs(np.asarray(nominal.signs, dtype=float)) - 1.0) == 0.0):
        raise DeriveError("nominal.signs: expected +1 or -1 per joint")
    for name in ("base", "tool"):
        dq.check_unit(np.asarray(getattr(nominal, name), dtype=float), f"nominal.{name}")


def held_joint(prog: IKProgram) -> int | None:
    """The index of the joint a program's free parameter is (``fv`` = q3 or q7: that joint is
    given, and the polish holds it), None without one; DeriveError for a free parameter that is
    not a joint (the SRS arm angle psi: near-class kernels take ``free="q3"``)."""
    if not prog.free:
        return None
    if not (prog.free.startswith("q") and prog.free[1:].isdigit()):
        raise DeriveError(f"{prog.robot}: near-class kernels of a 7-joint arm hold one joint at its given "
                          f"value; the free parameter {prog.free} is not a joint (use free='q3')")
    return int(prog.free[1:]) - 1


def nominal_program(robot, nominal: Nominal, free: str | None = None) -> IKProgram:
    """The IK program of a near-class arm: the nominal robot's program
    (:func:`derive.ik.program.ik_program`) after eight lines that move the pose into its frames,
    B^-1 P T^-1 (as :func:`derive.ik.program._related_program`), each solution mapped back to
    the arm's joints by q = s (q_N - o). The candidates are the nominal's; the kernels polish
    them (module docstring). ``free``: a 7-joint nominal's free parameter where its class offers
    a choice; it must be a joint (:func:`held_joint`), whose given value fv of the arm is the
    nominal's s fv + o."""
    robot = load_robot(robot)
    check_nominal(robot, nominal)
    nom = ik_program(nominal.robot, free)
    hold = held_joint(nom)
    p = sp.symbols("p0:8", real=True)
    moved_syms = sp.symbols("pn0:8", real=True)
    conj_b = [_number(x) for x in dq.conj_quaternion(np.asarray(nominal.base, dtype=float))]
    conj_t = [_number(x) for x in dq.conj_quaternion(np.asarray(nominal.tool, dtype=float))]
    moved = dual_hamilton(dual_hamilton(conj_b, p), conj_t)
    identity = [1, 0, 0, 0, 0, 0, 0, 0]
    rep = dict(zip(p, moved_syms))
    same = (list(map(float, nominal.base)) == identity and list(map(float, nominal.tool)) == identity)

    signs = [int(round(float(s))) for s in nominal.signs]
    offsets = [_number(o) for o in nominal.offsets]
    if hold is not None:         # the arm's given joint value fv is the nominal's s fv + o
        fv = sp.Symbol("fv", real=True)
        rep[fv] = signs[hold] * fv + offsets[hold]
        same = False

    def subs(e):
        return e if same or not isinstance(e, sp.Basic) else e.xreplace(rep)

    moved_same = (list(map(float, nominal.base)) == identity and list(map(float, nominal.tool)) == identity)
    if moved_same:
        rep = {k: v for k, v in rep.items() if k not in p}
    ops = [] if moved_same else [Op("let", str(s), sp.expand(e), depth=0) for s, e in zip(moved_syms, moved)]
    for op in nom.ops:
        args = op.args
        if op.kind == "require" and _reach_check(op.expr):
            continue
        if op.kind == "let" and isinstance(op.expr, sp.Basic) and op.expr.has(pos):
            # a root clipped at the edge of the nominal's reach: sqrt(|x|) instead of sqrt(max(x, 0)),
            # so that the two branches start on either side of the fold (where the arm's two
            # nearby roots are), not both on it
            op = Op(op.kind, op.name, op.expr.replace(pos, sp.Abs), op.name2, op.cond, op.other, op.args, op.depth)
        if op.kind == "solution":
            args = tuple(s * (subs(sp.sympify(a)) - o) for a, s, o in zip(op.args, signs, offsets))
        ops.append(Op(op.kind, op.name, subs(op.expr), op.name2, subs(op.cond), subs(op.other), args, op.depth))
    steps = [(f"pose in the frames of the nominal robot {nominal.robot.name}", "B^-1 P T^-1",
              [_comment_safe(nominal.how), f"relation mismatch {nominal.deviation:.2g}"]),
             *nom.steps,
             ("every candidate q = s (q_nominal - o)", "Newton polish",
              [f"damped Newton on the arm's own FK, at most {POLISH_MAX_ITER} steps, kept when "
               f"the residual is <= {POLISH_ACCEPT:g}"])]
    return IKProgram(robot.name, robot.dof, ops=ops, branches=nom.branches, free_joint=nom.free_joint,
                     free_rule=nom.free_rule + " (on the nominal robot, then polished)", steps=steps,
                     parameters=dict(nom.parameters), branch_labels=list(nom.branch_labels),
                     free=nom.free, free_doc=nom.free_doc, bit_weights=nom.bit_weights)


def _reach_check(expr) -> bool:
    """Whether a require line of the nominal program checks the nominal robot's reach (it holds
    one of the constants -REACH_TOL, an S1 discriminant's margin, or 1 + REACH_TOL, an acos
    argument's). Near-class kernels drop those lines: a pose the arm reaches may be out of the
    nominal's reach by about the mismatch (an elbow nearly stretched, a wrist centre near the
    shoulder's cylinder) or by much more on a branch near a singular set (the nominal's arm plane
    turns by about deviation / sin q5 near the wrist's); the roots are clipped instead
    (sqrt(|x|), acos of the clipped cosine) and the polish decides, after the candidates whose
    start misses the pose by more than SEED_KEEP deviations and that lie near no singular set
    are left out (as derive.ik.nearclass._near_reach)."""
    for f in sp.sympify(expr).atoms(sp.Float):
        x = float(f)
        if abs(abs(x) - REACH_TOL) <= 1e-6 * REACH_TOL or abs(x - (1.0 + REACH_TOL)) <= 1e-15:
            return True
    return False


def _comment_safe(text: str) -> str:
    """One line of text that ends neither a C comment nor a Python docstring."""
    out = " ".join(str(text).split()).replace("*/", "* /").replace(chr(92), "/")
    return out.replace(chr(34) * 3, chr(39) * 3)


def poe_chain(robot):
    """The product-of-exponentials form of a robot's FK: (w (n, 3) joint axes at q = 0, c (n, 3) a
    point of each axis, prismatic (n,) bools, variables (n,) indices into q, M (4, 4) the end frame
    at q = 0), checked against :func:`derive.kinematics.fk.fk_matrix` on random configurations."""
    robot = load_robot(robot)
    chain = numeric_chain(robot)
    if chain.n != robot.dof or sorted(chain.variables) != list(range(robot.dof)):
        raise DeriveError(f"{robot.name}: the path to the end frame does not move every joint variable "
                          "once; the polish needs a serial chain")
    for k, j in enumerate(robot.joints):
        if not j.is_mimic and float(j.multiplier) != 1.0:
            raise DeriveError(f"{robot.name}: joint {j.name!r} has a multiplier; the polish needs plain joints")
    w = np.asarray(chain.axes, dtype=float)
    w = w / np.linalg.norm(w, axis=1, keepdims=True)
    points = chain.start + np.concatenate([np.zeros((1, 3)), np.cumsum(chain.links, axis=0)])[:-1]
    prismatic = np.array([t != "revolute" for t in chain.types])
    variables = np.array(chain.variables)
    M = fk_matrix(robot, np.zeros(robot.dof))
    rng = np.random.default_rng(7)
    Q = rng.uniform(-np.pi, np.pi, (16, robot.dof))
    ref = fk_matrix(robot, Q)
    got = np.array([_poe_numpy(w, points, prismatic, variables, M, q) for q in Q])
    if np.max(np.abs(got - ref)) > 1e-9:
        raise DeriveError(f"{robot.name}: the product-of-exponentials FK does not reproduce the chain "
                          f"({np.max(np.abs(got - ref)):.2g}); the polish needs it")
    return w, points, prismatic, variables, M


def _poe_numpy(w, c, prismatic, variables, M, q) -> np.ndarray:
    T = np.eye(4)
    for i in range(len(w)):
        x = q[variables[i]]
        E = np.eye(4)
        if prismatic[i]:
            E[:3, 3] = w[i] * x
        else:
            K = np.array([[0, -w[i][2], w[i][1]], [w[i][2], 0, -w[i][0]], [-w[i][1], w[i][0], 0]])
            R = np.eye(3) + np.sin(x) * K + (1 - np.cos(x)) * (K @ K)
            E[:3, :3] = R
            E[:3, 3] = c[i] - R @ c[i]
        T = T @ E
    return T @ M


def _poe_code(robot, w, c, prismatic, variables, M) -> dict:
    """Straight-line code of the product of exponentials and the Jacobian's pieces: ``lines``
    [{"kind": "sincos", "s", "c", "var"} | {"kind": "let", "name", "e": sympy expression}], the
    end rotation ``R`` (9 names or expressions, row-major) and translation ``t`` (3), and per
    joint ``cols``: {"var", "prismatic", "z": 3, "c": 3} (the axis direction and a point of the
    axis in the current configuration)."""
    lines = []
    r = sp.eye(3)
    o = sp.zeros(3, 1)
    cols = []

    def let(name, e):
        e = sp.expand(e)
        if e.is_number:
            return sp.Float(float(e), 17) if not e.is_zero else sp.Integer(0)
        lines.append({"kind": "let", "name": name, "e": e})
        return sp.Symbol(name, real=True)

    def num(x):
        return _number(round(float(x), 17))

    for i in range(len(w)):
        wi = sp.Matrix([num(x) for x in w[i]])
        ci = sp.Matrix([num(x) for x in c[i]])
        z = sp.Matrix([let(f"z{i}_{a}", (r * wi)[a]) for a in range(3)])
        cp = sp.Matrix([let(f"c{i}_{a}", (r * ci + o)[a]) for a in range(3)])
        cols.append({"var": int(variables[i]), "prismatic": bool(prismatic[i]), "z": list(z), "c": list(cp)})
        v = int(variables[i])
        if prismatic[i]:
            qv = sp.Symbol(f"qv{v}", real=True)
            o = sp.Matrix([let(f"o{i}_{a}", (o + z * qv)[a]) for a in range(3)])
            continue
        s, co = sp.Symbol(f"s{i}", real=True), sp.Symbol(f"k{i}", real=True)
        lines.append({"kind": "sincos", "s": str(s), "c": str(co), "var": v})
        vc = sp.Symbol(f"v{i}", real=True)
        lines.append({"kind": "let", "name": str(vc), "e": 1 - co})
        K = sp.Matrix([[0, -wi[2], wi[1]], [wi[2], 0, -wi[0]], [-wi[1], wi[0], 0]])
        E = sp.eye(3) + s * K + vc * (K * K)
        rn = r * E
        r = sp.Matrix(3, 3, [let(f"r{i}_{a}{b}", rn[a, b]) for a in range(3) for b in range(3)])
        o = sp.Matrix([let(f"o{i}_{a}", (cp - r * ci)[a]) for a in range(3)])
    MR = sp.Matrix(3, 3, [num(M[a, b]) for a in range(3) for b in range(3)])
    Mt = sp.Matrix([num(M[a, 3]) for a in range(3)])
    R = [let(f"re{a}{b}", (r * MR)[a, b]) for a in range(3) for b in range(3)]
    t = [let(f"te{a}", (r * Mt + o)[a]) for a in range(3)]
    return {"lines": lines, "R": R, "t": t, "cols": cols}


def polish_context(robot, nominal: Nominal, printers: dict, hold: int | None = None) -> dict:
    """What the templates need to emit the polish: the product-of-exponentials code printed per
    language (``printers``: {"py": ..., "cc": ...}), the Jacobian's columns, the constants and the
    nominal's description."""
    robot = load_robot(robot)
    w, c, prismatic, variables, M = poe_chain(robot)
    code = _poe_code(robot, w, c, prismatic, variables, M)

    def pr(e):
        e = sp.sympify(e)
        return {lang: p.doprint(e) for lang, p in printers.items()}

    lines = []
    for d in code["lines"]:
        if d["kind"] == "let":
            lines.append({"kind": "let", "name": d["name"], **pr(d["e"])})
        else:
            lines.append(d)
    cols = [{"var": col["var"], "prismatic": col["prismatic"], "z": [pr(e) for e in col["z"]],
             "c": [pr(e) for e in col["c"]]} for col in sorted(code["cols"], key=lambda col: col["var"])]
    used = {d["name"] for d in lines if d["kind"] == "let"}
    prismatic_vars = sorted(col["var"] for col in cols if col["prismatic"])
    return {"lines": lines, "R": [pr(e) for e in code["R"]], "t": [pr(e) for e in code["t"]],
            "cols": cols, "lets": sorted(used), "prismatic_vars": prismatic_vars,
            "max_iter": POLISH_MAX_ITER, "stop": repr(POLISH_STOP), "accept": repr(POLISH_ACCEPT),
            "max_step": repr(POLISH_MAX_STEP), "last_step": repr(POLISH_LAST_STEP), "vec_steps": POLISH_VEC_STEPS, "metric": RESIDUAL_METRIC,
            "nominal": nominal.robot.name, "nominal_id": nominal.robot.id, "key": nominal_key(nominal),
            "deviation": f"{nominal.deviation:.3g}", "how": _comment_safe(nominal.how),
            "revolute": robot.revolute.tolist(), "hold": hold, **seed_context(robot.dof, nominal, hold)}


def seed_context(dof: int, nominal: Nominal, hold: int | None) -> dict:
    """The constants of the seeds near singular sets (derive.ik.nearclass._singular_seeds, emitted):
    a candidate whose Jacobian J (the free joints' columns) has lambda_min(J^T J) <
    ``seed_near`` lambda_max(J^T J), i.e. s_min / s_max < SEED_SINGULAR sqrt(deviation), lies
    near a singular set; ``seed_ts`` the offsets t (rad) of its seeds q + t v (v the unit
    eigenvector of lambda_min); ``free_idx`` the joints the polish moves."""
    r2 = max(float(nominal.deviation), 1e-12)
    r = math.sqrt(r2)
    ts = [t * r for t in SEED_FOLD] + list(SEED_TURN)
    keep = SEED_KEEP * r2 + 1e-9
    return {"seed_near": repr(SEED_SINGULAR ** 2 * r2), "seed_keep2": repr(keep * keep), "seed_ts": [repr(float(t)) for t in ts],
            "seed_sweeps": SEED_JACOBI_SWEEPS, "seed_max_iter": SEED_MAX_ITER, "free_idx": [k for k in range(dof) if k != hold]}
