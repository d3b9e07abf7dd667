"""CasADi functions of a robot: FK, pose error and its Jacobian, closed-form IK branches.

Every function is a ``casadi.Function`` over SX expressions:

* ``fk(q) -> dq`` (8): the unit dual quaternion [real w x y z, dual w x y z] of the end frame;
* ``fk_matrix(q) -> T`` (4x4);
* ``pose_error(q, target) -> (e, dpos, drot)``: the 6-vector residual e = [t - t*; 2 s v] with
  t, t* the translations and v the vector part of the rotation error r*^-1 r (s = +-1 picks
  the sign of its scalar part, so e does not depend on the sign of either dual quaternion;
  |2 s v| = 2 sin(angle / 2)), the position error |t - t*| (m) and the rotation angle
  2 atan2(|v|, |w|) (rad): a proper metric, zero exactly when the poses are equal;
* ``pose_error_jacobian(q, target) -> J`` (6 x dof): de/dq, by CasADi's algorithmic
  differentiation of the same expressions;
* ``ik(pose) -> (Q, valid)`` where a closed form exists (the UR family): Q (dof x 8) the 8
  branches of the closed form, valid (1 x 8) 1 where the branch is reachable; the function
  is total (no NaN: square roots of clipped arguments, atan2), unreachable branches are
  flagged instead of dropped, and duplicates are not merged (the C kernels merge them).

Where the expressions come from. ``fk`` of an exact library robot is the derived straight-line
code of the other kernels (:func:`derive.codegen.fk.fk_kernel`: the folded left sides of
B.36-B.42 times G) converted node by node; ``ik`` is the IK program of
:mod:`derive.ik.program` (the W.6, B.29-B.32, C.19/C.21, C.5/C.7 steps) with its branches
unrolled and ``if_else`` at the singular selections. Robots that are not exact (a calibrated
arm, a general 6R: :attr:`Robot.exact`) have no practical exact symbolic derivation: their DH
angles such as pi/2 + 0.002 make the exact products grow without bound; robots outside the
library are built without waiting for a derivation. For both, ``fk`` is the product of the
joint dual quaternions in the description's neutral form (Kunze eq. 1.8, 5.28; each rotation
cos(t/2) + sin(t/2) n, each translation 1 + eps v/2), built directly in SX. The test suite
checks that both constructions agree on the UR robots.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import casadi as ca
import sympy as sp

from derive.algebra.quaternion import dual_hamilton, hamilton
from derive.cache import (
    claim_folder,
    find_artifact,
    memo,
    step,
    store_artifacts,
    task,
    write_manifest,
)
from derive.codegen.emit import identifier
from derive.codegen.fk import fk_kernel
from derive.errors import DeriveError
from derive.ik.closed_form import has_closed_form
from derive.ik.redundant import redundant_kind
from derive.ik.ir import leaf_of, leaf_weights
from derive.ik.program import ik_program
from derive.model.robot import LIBRARY_DIR, load_robot

#: The functions written to generated/<robot>/ and the user cache (``ik`` only where a closed
#: form exists; ``residual`` is e and J in one call, for the refinement).
SAVED = ("fk", "fk_matrix", "pose_error", "pose_error_jacobian", "residual", "ik")
#: Those every robot has.
REQUIRED = SAVED[:-1]
#: Written besides for the SRS arms: ``ik_q3``, joint 3 given instead of the arm angle.
SRS_SAVED = ("ik_q3",)


# --------------------------------------------------------------------------- #
# sympy -> SX
# --------------------------------------------------------------------------- #
class _ToSX:
    """Converts sympy expressions to SX, with a symbol table and a node cache."""

    def __init__(self, env: dict):
        self.env = env
        self.cache: dict = {}

    def __call__(self, e):
        e = sp.sympify(e)
        hit = self.cache.get(e)
        if hit is not None:
            return hit
        out = self._convert(e)
        self.cache[e] = out
        return out

    def _convert(self, e):
        if e.is_Symbol:
            if e.name not in self.env:
                raise DeriveError(f"CasADi conversion: no value for {e.name}")
            return self.env[e.name]
        if e is sp.pi:
            return ca.SX(math.pi)
        if e.is_Number:
            return ca.SX(float(e))
        if e in (sp.true, sp.false):
            return ca.SX(1.0 if e is sp.true else 0.0)
        args = [self(a) for a in e.args]
        if isinstance(e, sp.Add):
            out = args[0]
            for a in args[1:]:
                out = out + a
            return out
        if isinstance(e, sp.Mul):
            out = args[0]
            for a in args[1:]:
                out = out * a
            return out
        if isinstance(e, sp.Pow):
            b, x = e.args
            if x == sp.Rational(1, 2):
                return ca.sqrt(args[0])
            if x == -1:
                return 1 / args[0]
            if x.is_Integer and x > 0:
                out = args[0]
                for _ in range(int(x) - 1):
                    out = out * args[0]
                return out
            return args[0] ** args[1]
        name = type(e).__name__
        table = {
            "sin": ca.sin, "cos": ca.cos, "atan2": ca.atan2, "Abs": ca.fabs,
            "sgn": lambda x: ca.copysign(1.0, x), "pos": lambda x: ca.fmax(x, 0.0),
            "acos": ca.acos, "asin": ca.asin, "atan": ca.atan,
            "StrictLessThan": lambda a, b: a < b, "LessThan": lambda a, b: a <= b,
            "StrictGreaterThan": lambda a, b: a > b, "GreaterThan": lambda a, b: a >= b,
            "Not": ca.logic_not,
        }
        if name in table:
            return table[name](*args)
        folds = {"Max": ca.fmax, "Min": ca.fmin, "And": ca.logic_and, "Or": ca.logic_or}
        if name in folds:                     # n-ary in sympy, binary in CasADi
            out = args[0]
            for a in args[1:]:
                out = folds[name](out, a)
            return out
        raise DeriveError(f"CasADi conversion: no rule for {name} ({e})")


# --------------------------------------------------------------------------- #
# FK expressions
# --------------------------------------------------------------------------- #
def _rotation(axis, angle):
    s, c = ca.sin(angle / 2), ca.cos(angle / 2)
    return [c, s * float(axis[0]), s * float(axis[1]), s * float(axis[2]), 0, 0, 0, 0]


def _translation(v):
    return [1, 0, 0, 0, 0, 0.5 * v[0], 0.5 * v[1], 0.5 * v[2]]


def _fk_product(robot, q, nominal=None, s=None):
    """The end frame's dual quaternion as the product of the joint motions (neutral form).

    With ``nominal`` (a robot of the same structure) and a symbol ``s``, every number of the
    description (offsets, translation vectors, rotation angles) is (1 - s) nominal + s robot:
    the geometry homotopy of :func:`homotopy_function` (s = 0 nominal, s = 1 robot)."""
    def mix(x, x0):
        return x if nominal is None else (1 - s) * x0 + s * x

    def op_dq(op, op0):
        if op.kind == "R":
            return _rotation(op.axis, mix(op.angle, op0.angle))
        return _translation([mix(float(x), float(x0)) for x, x0 in zip(op.vector, op0.vector)])

    joints0 = robot.joints if nominal is None else nominal.joints
    frames = []
    for j, j0 in zip(robot.joints, joints0):
        value = j.multiplier * q[j.variable] + j.mimic_offset + mix(j.offset, j0.offset)
        m = _rotation(j.axis, value) if j.type == "revolute" else _translation([value * float(a) for a in j.axis])
        for op, op0 in zip(reversed(j.pre), reversed(j0.pre)):
            m = dual_hamilton(op_dq(op, op0), m)
        for op, op0 in zip(j.post, j0.post):
            m = dual_hamilton(m, op_dq(op, op0))
        frames.append(m if j.parent < 0 else dual_hamilton(frames[j.parent], m))
    end = robot.ends[robot.default_end]
    end0 = end if nominal is None else nominal.ends[nominal.default_end]
    out = frames[end.parent]
    for op, op0 in zip(end.ops, end0.ops):
        out = dual_hamilton(out, op_dq(op, op0))
    return out


def same_structure(robot, nominal) -> bool:
    """True when the two descriptions differ only in their numbers (joint types, axes,
    parents, mimic relations and the kinds and axes of the fixed motions agree), so that
    the geometry homotopy between them is defined."""
    def kinds(ops):
        return [(o.kind, None if o.axis is None else tuple(o.axis)) for o in ops]

    def shape(r):
        end = r.ends[r.default_end]
        return [(j.type, tuple(j.axis), j.parent, j.variable, j.multiplier, j.mimic_offset,
                 kinds(j.pre), kinds(j.post)) for j in r.joints] + [(end.parent, kinds(end.ops))]
    return robot.dof == nominal.dof and shape(robot) == shape(nominal)


def _fk_derived(robot, q):
    """The derived straight-line FK of the other kernels (codegen.fk_kernel), in SX."""
    k = fk_kernel(robot)
    env = {f"q{i}": q[i] for i in range(robot.dof)}
    conv = _ToSX(env)
    for s, c, a in k.trig:
        if isinstance(a, tuple) and a[0] == "double":
            hs, hc = env[a[1]], env[a[2]]
            env[s], env[c] = 2 * hs * hc, 1 - 2 * hs * hs
        elif isinstance(a, tuple):         # ("sum", s_x, c_x, s_y, c_y, sign): x + sign y
            sx, cx, sy, cy, sign = env[a[1]], env[a[2]], env[a[3]], env[a[4]], a[5]
            env[s], env[c] = sx * cy + sign * cx * sy, cx * cy - sign * sx * sy
        else:
            x = conv(a)
            env[s], env[c] = ca.sin(x), ca.cos(x)
    for name, e in k.temps:
        env[str(name)] = conv(e)
    return [conv(e) for e in k.outputs]


def is_library_robot(robot) -> bool:
    return robot.path != "<dict>" and Path(robot.path).parent == LIBRARY_DIR


def _quat_to_matrix(r):
    w, x, y, z = r
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def _translation_of(d):
    """t = 2 dual real^* (vector part)."""
    conj = [d[0], -d[1], -d[2], -d[3]]
    return [2 * v for v in hamilton(d[4:], conj)[1:]]


def _split(v, n):
    return [v[i] for i in range(n)]


def _error_terms(d, t, tg):
    """e = [t - t*; 2 s v], |t - t*| and 2 atan2(|v|, |w|) for the FK d (translation t) and
    the target tg (module docstring)."""
    t_star = _translation_of(tg)
    err_q = hamilton([tg[0], -tg[1], -tg[2], -tg[3]], d[:4])       # r*^-1 r
    sgn = ca.if_else(err_q[0] >= 0, 1.0, -1.0)
    dt = [a - b for a, b in zip(t, t_star)]
    e = ca.vertcat(*dt, *[2 * sgn * v for v in err_q[1:]])
    dpos = ca.norm_2(ca.vertcat(*dt))
    drot = 2 * ca.atan2(ca.norm_2(ca.vertcat(*err_q[1:])), ca.fabs(err_q[0]))
    return e, dpos, drot


# --------------------------------------------------------------------------- #
# The functions
# --------------------------------------------------------------------------- #
def functions(robot, source: str | None = None) -> dict:
    """The CasADi functions of a robot: fk, fk_matrix, pose_error, pose_error_jacobian,
    residual (e and J in one call, for the refinement) and ik where the robot has a closed form
    (for the SRS arms also ik_q3: joint 3 given instead of the arm angle).

    Loaded from the artifacts of the robot's identity when they exist (the shipped
    ``generated/<robot>/*.casadi``, then the user cache, :mod:`derive.cache`); otherwise built
    (FK from the joint dual-quaternion product for robots outside the library or not exact: no symbolic
    work) and stored in the user cache. ``source`` "derived" or "product" forces a fresh build
    with that FK construction (default: derived for exact library robots, product otherwise).
    Cached per identity."""
    robot = load_robot(robot)
    if source is not None:
        return memo("casadi-functions", (robot.id, robot.limits_id, source), lambda: _functions(robot, source))
    return memo("casadi-functions", (robot.id, robot.limits_id, None), lambda: _load_or_build(robot))


def _load_or_build(robot) -> dict:
    found = {name: find_artifact(robot.id, f"casadi/{name}") for name in SAVED + SRS_SAVED}
    # a 7-joint arm's functions stored before its IK program existed are built again
    kind = redundant_kind(robot)
    if all(found[name] is not None for name in REQUIRED) and (found["ik"] is not None or kind is None) \
            and (found["ik_q3"] is not None or kind != "srs"):
        return {name: ca.Function.load(str(path)) for name, path in found.items() if path is not None}
    source = "derived" if is_library_robot(robot) and robot.exact else "product"
    with task(robot.name):
        step(f"no CasADi functions of identity {robot.id} in generated/ or the user cache: "
             f"building them ({source} FK)")
        fns = _functions(robot, source)
    with tempfile.TemporaryDirectory() as tmp:
        files = {}
        for name in SAVED + SRS_SAVED:
            if name in fns:
                path = Path(tmp) / f"{identifier(robot.name)}_{name}.casadi"
                fns[name].save(str(path))
                files[f"casadi/{name}"] = (path.name, path.read_bytes())
    store_artifacts(robot.id, files, {"robot": robot.name})
    return fns


def _functions(robot, source: str | None = None) -> dict:
    n = robot.dof
    if source is None:
        source = "derived" if is_library_robot(robot) and robot.exact else "product"
    q = ca.SX.sym("q", n)
    qs = _split(q, n)
    d = _fk_derived(robot, qs) if source == "derived" else _fk_product(robot, qs)
    dq_expr = ca.vertcat(*d)
    fns = {"fk": ca.Function("fk", [q], [dq_expr], ["q"], ["dq"])}
    t = _translation_of(d)
    mat = ca.vertcat(ca.horzcat(_quat_to_matrix(d[:4]), ca.vertcat(*t)), ca.DM([[0, 0, 0, 1]]))
    fns["fk_matrix"] = ca.Function("fk_matrix", [q], [mat], ["q"], ["T"])

    target = ca.SX.sym("target", 8)
    e, dpos, drot = _error_terms(d, t, _split(target, 8))
    jac = ca.jacobian(e, q)
    fns["pose_error"] = ca.Function("pose_error", [q, target], [e, dpos, drot],
                                    ["q", "target"], ["e", "dpos", "drot"])
    fns["pose_error_jacobian"] = ca.Function("pose_error_jacobian", [q, target], [jac],
                                             ["q", "target"], ["J"])
    fns["residual"] = ca.Function("residual", [q, target], [e, jac, dpos, drot],
                                  ["q", "target"], ["e", "J", "dpos", "drot"])
    if source == "derived":
        ik = _ik_function(robot)
        if ik is not None:
            fns["ik"] = ik
        if redundant_kind(robot) == "srs":
            fns["ik_q3"] = _ik_function(robot, "q3")
    return fns


def homotopy_function(robot, nominal):
    """``homotopy(q, s, target) -> (e, J)``: the pose error e (6) of the geometry
    (1 - s) nominal + s robot (every number of the two descriptions blended, see
    :func:`_fk_product`) and its Jacobian J = [de/dq, de/ds] (6 x (dof + 1)); the path
    tracking of :mod:`derive.refinement` follows e = 0 from a nominal solution at s = 0 to the
    robot at s = 1. Cached per (robot, nominal); DeriveError unless :func:`same_structure`."""
    robot, nominal = load_robot(robot), load_robot(nominal)
    if not same_structure(robot, nominal):
        raise DeriveError(f"{robot.name}: no geometry homotopy to {nominal.name}: the "
                          "descriptions differ in structure, not only in numbers")

    def build(r):
        n = r.dof
        q, s, target = ca.SX.sym("q", n), ca.SX.sym("s"), ca.SX.sym("target", 8)
        d = _fk_product(r, _split(q, n), nominal, s)
        e = _error_terms(d, _translation_of(d), _split(target, 8))[0]
        return ca.Function("homotopy", [q, s, target], [e, ca.jacobian(e, ca.vertcat(q, s))],
                           ["q", "s", "target"], ["e", "J"])
    return memo("casadi-homotopy", (robot.id, nominal.id), lambda: build(robot))


def _ik_function(robot, free: str | None = None):
    """The IK program's 8 branches in SX (None when the robot has no closed form):
    ``ik(pose) -> (Q, valid)``, and for a 7-joint arm ``ik(pose, free) -> (Q, valid)`` with its
    free parameter (the arm angle psi or q7, :mod:`derive.ik.program7`); with ``free`` = "q3"
    (SRS arms) the function ``ik_q3(pose, free)`` of the program with joint 3 given."""
    if not has_closed_form(robot) and redundant_kind(robot) is None:
        return None
    try:
        prog = ik_program(robot, free)
    except DeriveError:
        return None
    if any(op.kind == "roots4" for op in prog.ops):
        # the roots of a quartic (the three-parallel sp6 layout's subproblem 6) have no SX form:
        # CasADi has no polynomial root or eigenvalue function of symbolic arguments
        return None
    name = "ik" if free is None else f"ik_{free}"
    pose = ca.SX.sym("pose", 8)
    env = {f"p{i}": pose[i] for i in range(8)}
    fsym = ca.SX.sym("free") if prog.free else None
    if fsym is not None:
        env["fv"] = fsym
    sols, valid = [], []
    _run(prog.ops, 0, dict(env), ca.SX(1.0), sols, valid)
    if len(sols) != prog.branches:
        raise DeriveError(f"{robot.name}: IK program gave {len(sols)} branches, expected {prog.branches}")
    # _run visits the leaves in nesting order; the columns are in leaf (branch id) order
    depth = len(leaf_weights(prog))
    order = [leaf_of(prog, [(i >> (depth - 1 - d)) & 1 for d in range(depth)]) for i in range(len(sols))]
    sols, valid = ([x for _, x in sorted(zip(order, xs), key=lambda t: t[0])] for xs in (sols, valid))
    cols = [ca.vertcat(*[wrap_angle_sx(a) for a in s]) for s in sols]
    if fsym is not None:
        return ca.Function(name, [pose, fsym], [ca.horzcat(*cols), ca.horzcat(*valid)], ["pose", "free"],
                           ["Q", "valid"])
    return ca.Function("ik", [pose], [ca.horzcat(*cols), ca.horzcat(*valid)], ["pose"], ["Q", "valid"])


def wrap_angle_sx(a):
    """``a`` wrapped to (-pi, pi], the convention of :func:`derive.algebra.angles.wrap_angle`
    and of the generated kernels: a - 2 pi ceil((a - pi) / (2 pi))."""
    return a - 2 * math.pi * ca.ceil((a - math.pi) / (2 * math.pi))


def _run(ops, start, env, ok, sols, valid):
    """Interpret the program from ops[start]: a branch op runs the rest twice (+1, -1)."""
    conv = _ToSX(env)
    for i in range(start, len(ops)):
        op = ops[i]
        if op.kind == "let":
            env[op.name] = conv(op.expr)
        elif op.kind == "sincos":
            x = conv(op.expr)
            env[op.name], env[op.name2] = ca.sin(x), ca.cos(x)
        elif op.kind == "double":
            hs, hc = env[op.args[0]], env[op.args[1]]
            env[op.name], env[op.name2] = 2 * hs * hc, 1 - 2 * hs * hs
        elif op.kind == "require":
            ok = ca.logic_and(ok, conv(op.expr))
        elif op.kind == "flag":
            env[op.name] = conv(op.expr)
        elif op.kind == "select":
            env[op.name] = ca.if_else(conv(op.cond), conv(op.expr), conv(op.other))
        elif op.kind == "branch":
            for sign in (1.0, -1.0):
                sub = dict(env)
                sub[op.name] = ca.SX(sign)
                _run(ops, i + 1, sub, ok, sols, valid)
            return
        elif op.kind == "solution":
            sols.append([conv(a) for a in op.args])
            valid.append(ok)
        else:
            raise DeriveError(f"CasADi IK: unknown program line {op.kind}")


def write_casadi(robot, out_dir, force: bool = False) -> list[Path]:
    """Build the functions afresh and save them with ``Function.save`` into
    out_dir/<robot name>/<robot name>_<function>.casadi, recorded in the folder's manifest (a
    folder of another robot is refused unless ``force``: :func:`derive.cache.claim_folder`)."""
    robot = load_robot(robot)
    folder = Path(out_dir) / robot.name
    claim_folder(folder, robot.id, robot.name, force)
    folder.mkdir(parents=True, exist_ok=True)
    source = "derived" if is_library_robot(robot) and robot.exact else "product"
    fns = functions(robot, source)
    paths, roles = [], {}
    for name in SAVED + SRS_SAVED:
        if name in fns:
            p = folder / f"{identifier(robot.name)}_{name}.casadi"
            fns[name].save(str(p))
            paths.append(p)
            roles[f"casadi/{name}"] = p.name
    paths.append(write_manifest(folder, {"id": robot.id, "robot": robot.name, "files": roles}))
    return paths
