"""The dq-derive command line: forward and inverse kinematics, numerical refinement, generated
equations and kernels, and figures, for the robots of the library or a YAML / URDF file.

Arguments have the same names in every subcommand:
  --q Q [Q ...]        joint values, in joint order: radians for revolute joints, metres for
                       prismatic ones (with --deg: revolute joints in degrees)
  --xyz X Y Z          a Cartesian target: the end frame's position in metres, with its
                       orientation given by one of
  --rpy R P Y          roll, pitch, yaw about the fixed x, y, z axes, R = Rz(Y) Ry(P) Rx(R)
                       (radians; with --deg: degrees)
  --quat A B C D       a unit quaternion in the order given by --quat-order xyzw (scipy, ROS)
                       or wxyz (scalar first, as dq-derive); --quat-order is required
  --dq W X Y Z W X Y Z a unit dual quaternion [real w x y z | dual w x y z], dual = 1/2 t real
  --deg                every angle in and out in degrees: revolute joint values (prismatic
                       joints stay in metres) and rpy; without it, an angle beyond 2 pi in
                       magnitude gets a warning on stderr
  --json               the results as one JSON object on stdout: numbers, joint names, units

Exit codes:
  0  success
  1  no solution: the target is not reachable (ik), refine found no exact solution, or a pose
     of a path has no configuration (path)
  2  usage or input error: unknown option or robot, malformed number, wrong count of joint
     values, non-unit quaternion, a robot without a closed-form IK (ik, plot --ik-of: use
     refine), file that cannot be read or written; one line on stderr, never a traceback
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import textwrap
import time

import numpy as np

from derive import reference
from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.apps import path as cartesian
from derive.bench import BENCHES
from derive.cache import find_artifact, shipped_index
from derive.codegen.loader import kernels
from derive.errors import DeriveError, InputError
from derive.ik import general6r, nearclass
from derive.ik.free_joint import joint_range as free_joint_range, route as free_joint_route
from derive.ik.closed_form import parallel3_class, spherical_class
from derive.ik.nearclass import classify
from derive.ik.redundant import NAMES as FREE_NAMES
from derive.ik.redundant import free_parameter, redundant_kind
from derive.ik.srs import arm_angle, ik_joint
from derive.ik.srs import within_limits as srs_within_limits
from derive.kinematics.pose import from_position_quaternion, from_position_rpy, to_position_rpy
from derive.model.classify import classify as geometric_classify
from derive.model.robot import list_robots, load_robot

# The heavy modules (sympy, jinja2, CasADi, lxml, matplotlib and the benches: the emitters, the
# reports, refine, export, plot, bench) are imported inside the subcommands that use them, so
# that robots, fk, ik with a target, classify ... start without them (docs/architecture.md,
# "Light import"; tests/test_light_import.py).

#: Robots ``dq-derive generate`` (and so ``make generate``) works on by default.
DEFAULT_ROBOTS = ("ur3", "ur5")
#: Robots whose FK/IK kernels and CasADi functions ``dq-derive generate`` writes by default
#: (every UR robot), so that they load without a derivation.
UR_ROBOTS = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e")
#: Spherical-wrist robots whose outputs ``dq-derive generate`` writes by default: appendix, IK
#: report, kernels and CasADi functions of the first, kernels and CasADi functions of the rest.
#: Every other robot of the class gets them on request (``dq-derive kernels ROBOT`` ...).
SW_ROBOTS = ("irb120", "kr6-r900")
#: Seven-joint robots whose outputs ``dq-derive generate`` writes by default: appendix, IK report,
#: kernels and CasADi functions of the first of each class (Panda: q7 given, SRS: the arm angle
#: given), kernels and CasADi functions of the others.
SEVEN_ROBOTS = ("panda", "iiwa14", "fr3", "iiwa7")

#: A --quat typed with a few decimals is normalised when its norm is this close to 1.
QUAT_TOL = 1e-4
#: Exit codes (documented in the module docstring, the --help epilog and docs/cli.md).
EXIT_OK, EXIT_NO_SOLUTION, EXIT_INPUT = 0, 1, 2

_DESCRIPTION, _EPILOG = __doc__.split("\n\n", 1)
_EXIT_EPILOG = "Exit codes:" + __doc__.split("Exit codes:", 1)[1]


# --------------------------------------------------------------------------- #
# Numbers, joints and units
# --------------------------------------------------------------------------- #
def _clean(x: float, prec: int) -> float:
    """x rounded to ``prec`` decimals, with -0.0 turned into 0.0 (never prints "-0.000")."""
    return round(float(x), prec) + 0.0


def _fmt(values, width=10, prec=6) -> str:
    return " ".join(f"{_clean(v, prec):{width}.{prec}f}" for v in np.asarray(values, dtype=float).ravel())


def _jnum(x) -> float | None:
    """A float for JSON: -0.0 becomes 0.0; NaN and inf (which JSON lacks) become null."""
    x = float(x)
    return x + 0.0 if math.isfinite(x) else None


def _jlist(values) -> list:
    return [_jnum(v) for v in np.asarray(values, dtype=float).ravel()]


def _variables(robot):
    """The joints that carry a joint variable (mimic joints excluded), in q order."""
    return [j for j in robot.joints if not j.is_mimic]


def _units(robot, deg: bool) -> list[str]:
    return ["m" if j.type == "prismatic" else ("deg" if deg else "rad") for j in _variables(robot)]


def _angle_unit(deg: bool) -> str:
    return "deg" if deg else "rad"


#: An angle typed without --deg whose magnitude exceeds this (2 pi) was most likely meant in
#: degrees: it gets a warning on stderr (the value is still taken in radians).
ANGLE_WARN = 2 * math.pi


def _warn_angles(name: str, values, deg: bool, revolute=None) -> None:
    """Warn on stderr when an angle option given in radians (no --deg) has a value beyond 2 pi
    in magnitude, naming the option and suggesting --deg; ``revolute`` masks joint values (the
    prismatic ones are metres)."""
    if deg or values is None:
        return
    v = np.atleast_1d(np.asarray(values, dtype=float))
    mask = np.ones(v.shape, bool) if revolute is None else np.asarray(revolute, bool)
    big = v[mask & (np.abs(v) > ANGLE_WARN)]
    if big.size:
        print(f"dq-derive: warning: {name}: {', '.join(f'{x:g}' for x in big)} "
              f"{'is' if big.size == 1 else 'are'} beyond 2 pi in magnitude, taken as radians; "
              "for degrees add --deg", file=sys.stderr)


def _joints_in(robot, values, name: str, deg: bool) -> np.ndarray:
    """Joint values from the command line (revolute joints in degrees with --deg) in rad and m."""
    q = np.asarray(values, dtype=float)
    if q.size != robot.dof:
        raise InputError(f"{name}: robot {robot.name!r} has {robot.dof} joint variables "
                         f"({', '.join(robot.variable_names)}), got {q.size} value(s)")
    _warn_angles(name, q, deg, robot.revolute)
    if deg:
        q = np.where(robot.revolute, np.radians(q), q)
    return q


def _joints_out(robot, q, deg: bool) -> np.ndarray:
    """Joint values in rad and m as printed: revolute joints in degrees with --deg."""
    q = np.asarray(q, dtype=float)
    if not deg:
        return q
    return np.where(robot.revolute, np.degrees(q), q)


def _joint_meta(robot, deg: bool) -> list[dict]:
    return [{"name": j.name, "type": j.type, "unit": u} for j, u in zip(_variables(robot), _units(robot, deg))]


def _table(robot, rows, deg: bool, lead: list[tuple[str, str, int]], prec: int = 5) -> list[str]:
    """A table with one column per joint, headed by the joint's name and, below it, its unit.

    ``lead``: the columns before the joints as (title, second title line, width); ``rows``:
    (values of the lead columns as strings, joint values in rad and m, trailing note)."""
    names, units = robot.variable_names, _units(robot, deg)
    widths = [max(len(n), len(u) + 2, prec + 6) for n, u in zip(names, units)]
    head1 = " ".join(f"{t:>{w}}" for t, _, w in lead) + "  " + " ".join(f"{n:>{w}}" for n, w in zip(names, widths))
    head2 = " ".join(f"{t:>{w}}" for _, t, w in lead) + "  " + " ".join(f"{'(' + u + ')':>{w}}"
                                                                         for u, w in zip(units, widths))
    out = [head1.rstrip(), head2.rstrip()]
    for cells, q, note in rows:
        vals = _joints_out(robot, q, deg)
        line = (" ".join(f"{c:>{w}}" for c, (_, _, w) in zip(cells, lead)) + "  "
                + " ".join(f"{_clean(v, prec):{w}.{prec}f}" for v, w in zip(vals, widths)))
        out.append(line + (f"  {note}" if note else ""))
    return out


def _print_json(data) -> None:
    print(json.dumps(data, indent=2, allow_nan=False))


# --------------------------------------------------------------------------- #
# Targets: --q, --xyz with --rpy or --quat, --dq
# --------------------------------------------------------------------------- #
def _robot(args):
    """The robot of a subcommand: a library name, a YAML file or a URDF (--base, --tip)."""
    return load_robot(args.robot, base=args.base, tip=args.tip)


def _target(robot, args, what: str):
    """(pose (8,), joint values (rad, m) or None, JSON description) of the target options.

    Exactly one of --q, --xyz (with exactly one of --rpy and --quat) and --dq."""
    given = [o for o, v in (("--q", args.q), ("--xyz", args.xyz), ("--dq", args.dq)) if v is not None]
    if len(given) != 1:
        raise InputError(f"{what}: give exactly one target: --q (joint values whose pose is the "
                         "target), --xyz with --rpy or --quat, or --dq"
                         + (f" (got {' and '.join(given)})" if given else ""))
    if args.xyz is None and (args.rpy is not None or args.quat is not None):
        raise InputError(f"{what}: --rpy and --quat give the orientation of an --xyz target")
    if args.quat is None and args.quat_order is not None:
        raise InputError(f"{what}: --quat-order belongs with --quat")
    if args.q is not None:
        q = _joints_in(robot, args.q, "--q", args.deg)
        pose = reference.fk(robot, q)
        return pose, q, {"q": _jlist(args.q)}
    if args.dq is not None:
        pose = dq.check_unit(np.array(args.dq, dtype=float), "--dq")
        return pose, None, {"dq": _jlist(pose)}
    if (args.rpy is None) == (args.quat is None):
        raise InputError(f"{what}: --xyz needs its orientation: exactly one of --rpy R P Y or --quat A B C D")
    if args.rpy is not None:
        _warn_angles("--rpy", args.rpy, args.deg)
        rpy = np.radians(args.rpy) if args.deg else np.array(args.rpy, dtype=float)
        pose = from_position_rpy(np.array(args.xyz, dtype=float), rpy)
        return pose, None, {"xyz": _jlist(args.xyz), "rpy": _jlist(args.rpy)}
    if args.quat_order is None:
        raise InputError(f"{what}: --quat needs --quat-order xyzw (scipy, ROS) or wxyz (scalar first)")
    quat = np.array(args.quat, dtype=float)
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) > QUAT_TOL:
        raise InputError(f"--quat: not a unit quaternion (|q| = {norm:.6g}; within {QUAT_TOL:g} of 1 "
                         "it is normalised, so 4 printed decimals are enough)")
    pose = from_position_quaternion(np.array(args.xyz, dtype=float), quat / norm, args.quat_order)
    return pose, None, {"xyz": _jlist(args.xyz), "quat": _jlist(args.quat), "quat_order": args.quat_order}


def _pose_dict(pose, deg: bool) -> dict:
    t, rpy = to_position_rpy(pose)
    rpy = np.degrees(rpy) if deg else rpy
    return {"position": {"value": _jlist(t), "unit": "m"},
            "rpy": {"value": _jlist(rpy), "unit": _angle_unit(deg),
                    "convention": "R = Rz(yaw) Ry(pitch) Rx(roll)"},
            "quaternion_wxyz": _jlist(pose[:4]),
            "dual_quaternion": _jlist(pose)}


def _pose_lines(pose, deg: bool) -> list[str]:
    t, rpy = to_position_rpy(pose)
    unit = _angle_unit(deg)
    rpy = np.degrees(rpy) if deg else rpy
    return [
        f"  position (m):                        {_fmt(t, 9, 5)}",
        f"  roll pitch yaw ({unit}):               {_fmt(rpy, 9, 3 if deg else 5)}",
        f"  quaternion (w x y z):                {_fmt(pose[:4], 9, 5)}",
        f"  dual quaternion [w x y z | w x y z]: {_fmt(pose, 9, 5)}",
    ]


def _target_text(robot, pose, q, deg: bool) -> str:
    t, rpy = to_position_rpy(pose)
    rpy = np.degrees(rpy) if deg else rpy
    text = f"position {_fmt(t, 0, 5).strip()} m, rpy {_fmt(rpy, 0, 3 if deg else 5).strip()} {_angle_unit(deg)}"
    if q is not None:
        text += f" (the pose of q = {_fmt(_joints_out(robot, q, deg), 0, 4).strip()})"
    return text


# --------------------------------------------------------------------------- #
# Subcommands
# --------------------------------------------------------------------------- #
def _robot_row(name: str) -> dict:
    """Class and availability of one library robot (no search for related robots: fast)."""
    r = load_robot(name)
    c = geometric_classify(r)
    p3 = None if c.closed_form or spherical_class(r) is not None else parallel3_class(r)
    # the three-parallel layout with axes 5 and 6 apart: closed form (subproblem 6) in numpy and in
    # the kernels (its IK program's quartic roots have no CasADi form, so no CasADi ik)
    sp6 = p3 is not None and p3.layout != "intersecting"
    closed = "UR" if c.closed_form else ("OPW" if spherical_class(r) is not None else
                                         ("three parallel (sp6)" if sp6 else "three parallel") if p3 else "")
    kind = redundant_kind(r) if not closed else None
    cls = c.cls if c.cls == c.nominal_cls else f"{c.cls} (nominal {c.nominal_cls})"
    # a near-class arm (only where the description has near misses or names a nominal: fast)
    near = (not closed and not kind and (r.nominal or c.near_misses) and reference._near(r))
    # the general 6R route: what its derivation decided, from the cache without deriving (the
    # kernels' own test, derive.ik.general6r.status; "unchecked" until it is first derived)
    route = not closed and not kind and not near and _general_6r(r)
    g6 = general6r.status(r) if route else None
    ik = closed or (f"{'Panda' if kind == 'panda' else 'SRS'}, {FREE_NAMES[kind]} free" if kind else
                    f"nominal {nearclass.nominal_class(r)} + Newton polish" if near else
                    f"no: refine, seeded by {r.nominal}" if r.nominal else
                    ("no: refine (the general 6R elimination degenerates)" if g6 == "degenerate" else
                     "general 6R elimination") if _general_6r(r) else
                    "any joint given" if _seven_revolute(r) else "no: refine")
    # the seven-joint arms' kernels solve IK with the free parameter; a near-class 6R arm's kernels
    # run the nominal's closed form and polish (derive.codegen.polish), a seven-joint one's with
    # joint 3 given; any other 6R arm's kernels the general 6R elimination (up to 16 solutions)
    # when its elimination is regular with Q of rank 8 (derive.codegen.general6r)
    general = route and g6 in ("kernels", "unchecked")
    has_ik = bool(closed or kind or (near and r.dof == 6) or general)
    given = " (q3 given)" if near and r.dof == 7 else ""
    given += " (elimination unchecked)" if general and g6 == "unchecked" else ""
    # any other seven-revolute arm: no default IK kernel, but derive.kernels(r, backend, free="qK")
    # solves it with joint K given (numpy, and C by the general elimination where it has a plan)
    any_joint = " (+IK: free=qK)" if ik == "any joint given" else ""
    return {"name": name, "dof": r.dof, "joints": list(r.variable_names),
            "types": [j.type for j in _variables(r)], "class": cls,
            "closed_form_ik": closed or (("Panda" if kind == "panda" else "SRS") if kind else
                                         f"nominal {nearclass.nominal_class(r)} + polish" if near else None),
            "free_parameter": FREE_NAMES[kind] if kind else None,
            "ik": ik,
            "kernels": ("FK+IK" if has_ik or given else "FK") + (f" ({FREE_NAMES[kind]} free)" if kind else given + any_joint)
                       + ", " + _where(r.id, "c_source"),
            "casadi": ("fk, residual, ik" if has_ik and not route and not sp6 else "fk, residual") + ", " + _where(r.id, "casadi/fk"),
            "convention": r.convention, "title": r.title}


def _general_6r(robot) -> bool:
    """Whether the numpy reference solves a robot outside every special class by the general 6R
    elimination (derive.ik.general6r): six revolute joints, no mimic joint."""
    return robot.dof == 6 and all(j.type == "revolute" and not j.is_mimic for j in robot.joints)


def _seven_revolute(robot) -> bool:
    """Whether a robot outside the 7R classes is solved with any one joint given
    (derive.ik.free_joint): seven revolute joints, no mimic joint."""
    return robot.dof == 7 and all(j.type == "revolute" and not j.is_mimic for j in robot.joints)


def _where(robot_id: str, role: str) -> str:
    """Where an artifact of a robot comes from: "shipped" (in the package's generated/ folder),
    "cached" (derived earlier, in the user cache) or "on demand" (derived on first use)."""
    path = find_artifact(robot_id, role)
    if path is None:
        return "on demand"
    return "shipped" if path.parent == shipped_index().get(robot_id) else "cached"


def _robots_table(rows) -> list[str]:
    cols = [("name", "name", "<"), ("dof", "dof", ">"), ("class", "class", "<"),
            ("closed-form IK", "ik", "<"), ("kernels (C, numpy, Python)", "kernels", "<"),
            ("CasADi functions", "casadi", "<"), ("title", "title", "<")]
    widths = [max(len(h), *(len(str(r[k])) for r in rows)) for h, k, _ in cols]
    out = ["  ".join(f"{h:{a}{w}}" for (h, _, a), w in zip(cols, widths)).rstrip()]
    for r in rows:
        out.append("  ".join(f"{str(r[k]):{a}{w}}" for (_, k, a), w in zip(cols, widths)).rstrip())
    return out


def cmd_robots(args) -> int:
    rows = [_robot_row(name) for name in list_robots()]
    if args.json:
        _print_json({"robots": rows})
        return EXIT_OK
    for line in _robots_table(rows):
        print(line)
    print("closed-form IK: UR = the UR family, OPW = the spherical-wrist class, three parallel = "
          "axes 2, 3, 4 parallel (sp6: axes 5 and 6 apart, a quartic per pose, so no CasADi ik), Panda / SRS = the "
          "seven-joint classes with a free parameter (q7 / the arm angle psi: ik --free V, --sweep N, "
          "--seed Q; SRS also with joint 3 given: --free V --free-joint 3), nominal X + Newton polish = "
          "a near-class arm solved by its nominal robot's closed form and Newton steps on its own FK; "
          "any joint given = a seven-revolute arm solved with any joint J held (ik --free V --free-joint J; "
          "kernels with free='qJ', numpy and C); "
          "(elimination unchecked) = a general 6R arm not derived yet (the library's general arms ship "
          "their derivation's decision): its kernels have IK when its "
          "elimination is regular, checked on first use (dq-derive kernels or ik); kernels and CasADi "
          "functions: shipped in the package, cached (derived earlier), or derived on first use and cached")
    return EXIT_OK


def cmd_fk(args) -> int:
    robot = _robot(args)
    positional = getattr(args, "q_positional", None)     # absent when none are given (SUPPRESS)
    if args.q is not None and positional:
        raise InputError("fk: give the joint values once, as --q (or, deprecated, positionally)")
    values = args.q if args.q is not None else positional
    if not values:
        raise InputError("fk: give the joint values with --q")
    q = _joints_in(robot, values, "--q" if args.q is not None else "joint values", args.deg)
    end = args.end or robot.default_end
    pose = reference.fk(robot, q, args.end)
    if args.json:
        data = {"robot": robot.name, "end": end, "joints": _joint_meta(robot, args.deg),
                "q": _jlist(values), **_pose_dict(pose, args.deg)}          # q as given
        if args.matrix:
            data["matrix"] = [_jlist(row) for row in reference.fk_matrix(robot, q, args.end)]
        _print_json(data)
        return EXIT_OK
    print(f"{robot.name}: end frame {end!r} at")
    for line in _table(robot, [([], q, "")], args.deg, [], prec=4):
        print("  " + line)
    for line in _pose_lines(pose, args.deg):
        print(line)
    if args.matrix:
        print("  4x4 matrix (independent matrix product; rotation, translation in m):")
        for row in reference.fk_matrix(robot, q, args.end):
            print("   ", _fmt(row, 10, 6))
    return EXIT_OK


def cmd_classify(args) -> int:
    """Kinematic class of a robot: consecutive axes, spherical wrist, UR / OPW / SRS."""
    c = classify(_robot(args))
    print(json.dumps(c.to_dict(), indent=2) if args.json else c.report())
    return EXIT_OK


def _report(paths, t0=None, as_json=False) -> int:
    if as_json:
        _print_json({"written": [str(p) for p in paths]})
        return EXIT_OK
    for p in paths:
        print(f"wrote {p}")
    if t0 is not None:
        print(f"took {time.perf_counter() - t0:.2f} s")
    return EXIT_OK


def cmd_appendix(args) -> int:
    from derive.reports.appendix import write_appendix
    t0 = time.perf_counter()
    return _report(write_appendix(_robot(args), args.out, progress=not (args.quiet or args.json)), t0, args.json)


def _deprecated(args, old: str, new: str, attr_old: str, attr_new: str) -> None:
    """Move a deprecated option's value to its new name (error if both are given)."""
    if getattr(args, attr_old, None) is None:
        return
    if getattr(args, attr_new) is not None:
        raise InputError(f"{old} is the deprecated spelling of {new}: give only {new}")
    print(f"dq-derive: note: {old} is deprecated, use {new}", file=sys.stderr)
    setattr(args, attr_new, getattr(args, attr_old))


def cmd_ik(args) -> int:
    _deprecated(args, "ik --pose", "--q", "pose_old", "q")
    if args.q is None and args.xyz is None and args.dq is None:
        if (args.seed is not None or args.within_limits or args.rpy is not None or args.quat is not None
                or args.free is not None or args.sweep is not None or args.free_joint is not None):
            raise InputError("ik: --seed, --within-limits, --free, --free-joint, --sweep, --rpy and --quat need a "
                             "target (--q, --xyz or --dq)")
        from derive.reports.ik_report import write_ik
        t0 = time.perf_counter()
        return _report(write_ik(_robot(args), args.out, progress=not (args.quiet or args.json)), t0, args.json)
    robot = _robot(args)
    pose, q, target = _target(robot, args, "ik")
    deg = args.deg
    head = {"robot": robot.name, "target": {"given": target, **_pose_dict(pose, deg)},
            "joints": _joint_meta(robot, deg)}
    if (robot.dof == 7 and args.free_joint is not None
            and not (args.free_joint == 3 and (reference._near(robot) or redundant_kind(robot) == "srs"))):
        return _ik_free_joint(robot, args, pose, q, head)
    if reference._near(robot):
        return _ik_near(robot, args, pose, q, head)
    if redundant_kind(robot) is not None:
        return _ik_redundant(robot, args, pose, q, head)
    if args.free is not None or args.sweep is not None or args.free_joint is not None:
        raise InputError(f"ik: --free, --free-joint and --sweep are for the seven-joint arms with a free parameter "
                         f"(panda, fr3: q7; iiwa7, iiwa14: the arm angle psi); {robot.name} has none")
    if args.seed is not None:
        seed = _joints_in(robot, args.seed, "--seed", deg)
        res = kernels(robot, "c").nearest(pose, seed)
        if not res.found:
            return _no_solution(robot, args, head, "no solution inside the joint limits")
        conv = np.degrees if deg else (lambda x: x)
        sol = {"q": _jlist(_joints_out(robot, res.q, deg)), "branch": int(res.branch),
               "singular": bool(res.singular)}
        if args.json:
            _print_json({**head, "count": 1, "selection": "nearest to the seed, within the limits",
                         "largest_move": _jnum(conv(res.max_move)), "summed_move": _jnum(conv(res.total_move)),
                         "move_unit": _angle_unit(deg), "solutions": [sol], "reason": ""})
            return EXIT_OK
        print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
        print(f"the solution nearest to the seed, within the joint limits (largest joint move "
              f"{_clean(conv(res.max_move), 5):g} {_angle_unit(deg)}, summed "
              f"{_clean(conv(res.total_move), 5):g} {_angle_unit(deg)}):")
        note = f"branch {int(res.branch)}" + (", singular" if res.singular else "")
        for line in _table(robot, [(["1"], res.q, note)], deg, [("#", "", 3)]):
            print(line)
        return EXIT_OK
    if args.within_limits:
        sols, count, branch, sing = kernels(robot, "c").ik(pose, within_limits=True, details=True)
        rows = [(s, f"branch {int(b)}" + (", singular" if g else ""), {"branch": int(b), "singular": bool(g)})
                for s, b, g in zip(sols[:count], branch[:count], sing[:count])]
        reason = "" if count else "no solution inside the joint limits"
        what = "inside the joint limits, every 2 pi winding"
    else:
        sols = reference.ik(robot, pose, q_ref=q)
        rows = [(s, "singular: the free wrist joint from --q" if g and q is not None else
                 ("singular: the free wrist joint chosen" if g else ""), {"singular": bool(g)})
                for s, g in zip(sols, sols.singular)]
        reason = sols.reason
        what = ("closed form" if nearclass.exact_class(robot) else
                "general 6R elimination, numpy reference" if _general_6r(robot) else "closed form")
    if not rows:
        return _no_solution(robot, args, head, reason or "no solution")
    if args.json:
        _print_json({**head, "count": len(rows), "selection": what, "reason": "",
                     "solutions": [{"q": _jlist(_joints_out(robot, s, deg)), **extra} for s, _, extra in rows]})
        return EXIT_OK
    print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
    print(f"{len(rows)} solution(s) ({what}):")
    for line in _table(robot, [([str(i + 1)], s, note) for i, (s, note, _) in enumerate(rows)], deg,
                       [("#", "", 3)]):
        print(line)
    return EXIT_OK


def _ik_near(robot, args, pose, q, head) -> int:
    """ik of a near-class arm (no exact class, a nominal robot of one): the nominal's closed form +
    Newton polish (derive.reference.ik), residual and iterations per solution. Seven joints:
    --free V with --free-joint 3 (SRS class) or --free V = q7 (Panda class). --seed: the solution
    nearest to the seed inside the joint limits."""
    deg = args.deg
    if args.sweep is not None:
        raise InputError(f"ik: --sweep is not available for {robot.name} (a near-class arm: solved "
                         "with a joint given, --free V" + (" --free-joint 3)" if robot.dof == 7 else ")"))
    free = free_name = None
    if robot.dof == 7:
        if args.free is None:
            raise InputError(f"ik: {robot.name} has 7 joints: give --free V, the value of the joint held "
                             f"({'--free-joint 3' if nearclass.nominal_class(robot) == 'SRS' else 'q7'})")
        free = math.radians(args.free) if deg else float(args.free)
        free_name = f"q{args.free_joint}" if args.free_joint is not None else None
    elif args.free is not None or args.free_joint is not None:
        raise InputError(f"ik: --free and --free-joint are for seven-joint arms; {robot.name} has {robot.dof}")
    seed = None if args.seed is None else _joints_in(robot, args.seed, "--seed", deg)
    within = args.within_limits or seed is not None
    sols = reference.ik(robot, pose, q_ref=q, within_limits=within, sort_by=seed, free=free,
                        free_name=free_name)
    if seed is not None:
        sols = sols[:1]
    line = nearclass.describe(robot)
    rows = [(s, f"residual {r:.1e}, {int(k)} Newton step(s)" + (", singular" if g else ""),
             {"singular": bool(g), "residual": float(r), "iterations": int(k)})
            for s, g, r, k in zip(sols, sols.singular, sols.residual, sols.iterations)]
    head = {**head, "solved_by": line, "polish": sols.polish}
    if not rows:
        return _no_solution(robot, args, head, sols.reason or "no solution")
    what = ("nearest to the seed, within the joint limits" if seed is not None else
            "nominal closed form + Newton polish" + (", inside the joint limits" if within else ""))
    if args.json:
        _print_json({**head, "count": len(rows), "selection": what, "reason": "",
                     "solutions": [{"q": _jlist(_joints_out(robot, s, deg)), **extra} for s, _, extra in rows]})
        return EXIT_OK
    print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
    print(f"class: {geometric_classify(robot).cls}; {line}")
    print(f"{len(rows)} solution(s) ({what}; {sols.polish}):")
    for line in _table(robot, [([str(i + 1)], s, note) for i, (s, note, _) in enumerate(rows)], deg,
                       [("#", "", 3)]):
        print(line)
    return EXIT_OK


def _ik_redundant(robot, args, pose, q, head) -> int:
    """ik of a seven-joint arm: at --free V, over --sweep N values, or nearest to --seed."""
    deg = args.deg
    unit = _angle_unit(deg)
    conv = np.degrees if deg else (lambda x: x)
    name, (lo, hi) = free_parameter(robot)
    given = [o for o, v in (("--free", args.free), ("--sweep", args.sweep), ("--seed", args.seed))
             if v is not None]
    if len(given) != 1:
        what = ("q7, the value of joint 7" if name == "q7" else
                "psi, the arm angle: the rotation of the arm plane about the shoulder-wrist line")
        raise InputError(f"ik: {robot.name} has 7 joints and a one-parameter family of solutions per "
                         f"pose: give exactly one of --free V ({what}; {unit}), --sweep N (N values "
                         "over its feasible range) or --seed Q (the solution nearest to Q)"
                         + (f" (got {' and '.join(given)})" if given else ""))
    _warn_angles("--free", args.free, deg)
    free_meta = {"name": name, "unit": unit, "range": [_jnum(conv(lo)), _jnum(conv(hi))]}
    head = {**head, "free_parameter": free_meta}
    if args.seed is not None:
        if args.within_limits:
            raise InputError("ik: --seed already chooses within the joint limits; drop --within-limits")
        seed = _joints_in(robot, args.seed, "--seed", deg)
        res = reference.nearest(robot, pose, seed)
        if not res.found:
            return _no_solution(robot, args, head, "no solution inside the joint limits")
        value = float(res.q[6]) if name == "q7" else float(arm_angle(robot, res.q))
        sol = {"q": _jlist(_joints_out(robot, res.q, deg)), "free": _jnum(conv(value)),
               "branch": int(res.branch), "singular": bool(res.singular)}
        if args.json:
            _print_json({**head, "count": 1, "selection": f"nearest to the seed, within the limits, {name} "
                         "chosen by a 1D search", "largest_move": _jnum(conv(res.max_move)),
                         "summed_move": _jnum(conv(res.total_move)), "move_unit": unit,
                         "solutions": [sol], "reason": ""})
            return EXIT_OK
        print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
        print(f"the solution nearest to the seed, within the joint limits, {name} = "
              f"{_clean(conv(value), 5):g} {unit} (largest joint move {_clean(conv(res.max_move), 5):g} "
              f"{unit}, summed {_clean(conv(res.total_move), 5):g} {unit}):")
        note = f"branch {int(res.branch)}" + (", singular" if res.singular else "")
        for line in _table(robot, [(["1"], res.q, note)], deg, [("#", "", 3)]):
            print(line)
        return EXIT_OK
    if args.free_joint is not None:
        if name != "psi" or args.free_joint != 3 or args.free is None:
            raise InputError("ik: --free-joint 3 (with --free V, the value of joint 3) is for the SRS "
                             f"arms (iiwa7, iiwa14); {robot.name}: "
                             + ("its free parameter is q7" if name != "psi" else
                                "only joint 3" if args.free_joint != 3 else "give --free V"))
        value = math.radians(args.free) if deg else float(args.free)
        res = ik_joint(robot, pose, 3, value, q_ref=q)
        keep = np.arange(res.count)
        if args.within_limits:
            keep = keep[srs_within_limits(robot, res.q[:res.count])]
        rows = [(value, res.q[i], res.branch[i], res.singular[i]) for i in keep]
        name = "q3"
        head = {**head, "free_parameter": {**free_meta, "name": "q3",
                                           "range": [_jnum(conv(x)) for x in robot.limits[2]]}}
        what = (f"closed form at q3 = {_clean(args.free, 6):g} {unit}"
                + (", inside the joint limits" if args.within_limits else ""))
        reason = res.reason or ("" if rows else "no solution inside the joint limits")
    elif args.sweep is not None:
        if args.sweep < 1:
            raise InputError(f"--sweep: the number of values of {name}, an integer >= 1; got {args.sweep}")
        sw = reference.ik_sweep(robot, pose, args.sweep, q_ref=q)
        rows = [(v, s, b, g) for v, sols, c, br, sg in zip(sw.free, sw.q, sw.counts, sw.branch, sw.singular)
                for s, b, g in zip(sols[:c], br[:c], sg[:c])]
        what = (f"{len(sw.free)} values of {name} over its feasible range, the solutions inside the "
                "joint limits")
        reason = "" if rows else f"no solution inside the joint limits at any of the {args.sweep} values of {name}"
    else:
        value = math.radians(args.free) if deg else float(args.free)
        sols = reference.ik(robot, pose, q_ref=q, within_limits=args.within_limits, free=value)
        rows = [(value, s, b, g) for s, b, g in zip(sols, sols.branch, sols.singular)]
        what = (f"closed form at {name} = {_clean(args.free, 6):g} {unit}"
                + (", inside the joint limits, every 2 pi winding" if args.within_limits else ""))
        reason = sols.reason
    return _free_rows(robot, args, head, pose, q, rows, what, reason, name, branches=True)


def _ik_free_joint(robot, args, pose, q, head) -> int:
    """ik of a seven-joint arm with joint J given (--free-joint J, any J but the SRS class's 3,
    which _ik_redundant answers): at --free V, over --sweep N values of joint J, or nearest to
    --seed Q with joint J chosen for the path (derive.ik.free_joint through derive.reference)."""
    deg = args.deg
    unit = _angle_unit(deg)
    conv = np.degrees if deg else (lambda x: x)
    k = args.free_joint
    name = f"q{k}"
    given = [o for o, v in (("--free", args.free), ("--sweep", args.sweep), ("--seed", args.seed))
             if v is not None]
    if len(given) != 1:
        raise InputError(f"ik: --free-joint {k}: give exactly one of --free V (the value of joint {k}; {unit}), "
                         f"--sweep N (N values over its range) or --seed Q (the solution nearest to Q)"
                         + (f" (got {' and '.join(given)})" if given else ""))
    if not 1 <= k <= 7:
        raise InputError(f"ik: --free-joint: a joint of {robot.name}, 1 to 7; got {k}")
    lo, hi = free_joint_range(robot, k)
    head = {**head, "free_parameter": {"name": name, "unit": unit, "range": [_jnum(conv(lo)), _jnum(conv(hi))]}}
    if args.seed is not None:
        seed = _joints_in(robot, args.seed, "--seed", deg)
        res = reference.nearest(robot, pose, seed, free_name=name)
        if not res.found:
            return _no_solution(robot, args, head, "no solution inside the joint limits")
        rows = [(float(res.q[k - 1]), res.q, res.branch, res.singular)]
        what = f"nearest to the seed, within the limits, {name} chosen by a 1D search"
        reason = ""
    elif args.sweep is not None:
        if args.sweep < 1:
            raise InputError(f"--sweep: the number of values of {name}, an integer >= 1; got {args.sweep}")
        sw = reference.ik_sweep(robot, pose, args.sweep, q_ref=q, free_name=name)
        rows = [(v, s, b, g) for v, sols, c, br, sg in zip(sw.free, sw.q, sw.counts, sw.branch, sw.singular)
                for s, b, g in zip(sols[:c], br[:c], sg[:c])]
        what = f"{len(sw.free)} values of {name} over its range, the solutions inside the joint limits"
        reason = "" if rows else f"no solution inside the joint limits at any of the {args.sweep} values of {name}"
    else:
        _warn_angles("--free", args.free, deg)
        value = math.radians(args.free) if deg else float(args.free)
        sols = reference.ik(robot, pose, q_ref=q, within_limits=args.within_limits, free=value, free_name=name)
        rows = [(value, s, b, g) for s, b, g in zip(sols, sols.branch, sols.singular)]
        what = (f"{name} = {_clean(args.free, 6):g} {unit} given, the other six by the "
                f"{free_joint_route(robot, k)} route" + (", inside the joint limits" if args.within_limits else ""))
        reason = sols.reason
    return _free_rows(robot, args, head, pose, q, rows, what, reason, name, branches=False)


def _free_rows(robot, args, head, pose, q, rows, what: str, reason, name: str, branches: bool) -> int:
    """Print the solutions of a seven-joint arm's ik at given values of its free parameter or
    joint ``name``: ``rows`` of (value, q, branch, singular); JSON with --json. ``branches``:
    the table names each solution's branch (the general route of a given joint has none)."""
    deg = args.deg
    unit = _angle_unit(deg)
    conv = np.degrees if deg else (lambda x: x)
    if not rows:
        return _no_solution(robot, args, head, reason or "no solution")
    if args.json:
        _print_json({**head, "count": len(rows), "selection": what, "reason": "",
                     "solutions": [{"q": _jlist(_joints_out(robot, s, deg)), "free": _jnum(conv(v)),
                                    "branch": int(b), "singular": bool(g)} for v, s, b, g in rows]})
        return EXIT_OK
    print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
    print(f"{len(rows)} solution(s) ({what}):")
    lead = [("#", "", 3), (name, f"({unit})", 10)]
    table = [([str(i + 1), f"{_clean(conv(v), 5):.5f}"], s,
              (f"branch {int(b)}" + (", singular" if g else "")) if branches else ("singular" if g else ""))
             for i, (v, s, b, g) in enumerate(rows)]
    for line in _table(robot, table, deg, lead):
        print(line)
    return EXIT_OK


def _no_solution(robot, args, head, reason: str) -> int:
    reason = reason.strip().lstrip(":").strip()
    if args.json:
        _print_json({**head, "count": 0, "solutions": [], "reason": reason})
    else:
        print(f"{robot.name}: no solution: {reason}")
    return EXIT_NO_SOLUTION


def cmd_refine(args) -> int:
    """Refine IK solutions on the robot's model; the target from --q, --xyz or --dq."""
    from derive.refinement.solver import refine
    _deprecated(args, "refine --pose", "--dq", "pose_old", "dq")
    robot = _robot(args)
    pose, q, target = _target(robot, args, "refine")
    t0 = time.perf_counter()
    res = refine(robot, pose, weights=(args.w_pos, args.w_rot), regularization=args.reg,
                 tol=args.tol, max_iter=args.max_iter)
    dt = time.perf_counter() - t0
    deg = args.deg
    if args.json:
        _print_json({"robot": robot.name, "target": {"given": target, **_pose_dict(pose, deg)},
                     "joints": _joint_meta(robot, deg), "success": bool(res.success),
                     "distinct_solutions": len(res.solutions),
                     "results": [{"seed": r.seed, "success": bool(r.success), "iterations": int(r.iterations),
                                  "position_error": {"value": _jnum(r.position_error), "unit": "m"},
                                  "rotation_error": {"value": _jnum(math.degrees(r.rotation_error) if deg
                                                                    else r.rotation_error),
                                                     "unit": _angle_unit(deg)},
                                  "solver": r.solver, "q": _jlist(_joints_out(robot, r.q, deg)),
                                  "note": r.note} for r in res]})
        return EXIT_OK if res.success else EXIT_NO_SOLUTION
    print(f"{robot.name}: target {_target_text(robot, pose, q, deg)}")
    print(f"{len(res)} seed(s), {len(res.solutions)} distinct exact solution(s) in {dt * 1e3:.1f} ms")
    rot = math.degrees if deg else float
    lead = [("seed", "", 4), ("ok", "", 3), ("iter", "", 4), ("|dp|", "(m)", 8),
            ("angle", f"({_angle_unit(deg)})", 8), ("solver", "", 13)]
    rows = [([str(r.seed), "yes" if r.success else "no", str(r.iterations), f"{r.position_error:.1e}",
              f"{rot(r.rotation_error):.1e}", r.solver], r.q, "") for r in res]
    for line in _table(robot, rows, deg, lead):
        print(line)
    for r in res:
        if r.note:
            print(f"seed {r.seed}: {r.note}")
    if not res.success:
        print(f"no exact solution: best residual {res.best.position_error:.3e} m, "
              f"{rot(res.best.rotation_error):.3e} {_angle_unit(deg)}")
    return EXIT_OK if res.success else EXIT_NO_SOLUTION


def cmd_export(args) -> int:
    """Write the robot as a kinematic URDF and/or as our YAML (convention urdf)."""
    from derive.model import export
    robot = _robot(args)
    if args.urdf is None and args.yaml is None:
        raise InputError("export: give --urdf FILE and/or --yaml FILE")
    return _report(export.write(robot, args.urdf, args.yaml), as_json=args.json)


def cmd_kernels(args) -> int:
    from derive.codegen.emit import write_ikfast, write_kernels
    robot = _robot(args)
    written = write_kernels(robot, args.out)
    if args.ikfast:
        written += write_ikfast(robot, args.out)
    return _report(written, as_json=args.json)


def cmd_plot(args) -> int:
    """The arm at --q, or every IK solution of the pose of --ik-of, as a PNG."""
    from derive.reports.figures import arm_figure, ik_figure
    robot = _robot(args)
    if (args.q is None) == (args.ik_of is None):
        raise InputError("plot: give exactly one of --q (draw the arm) and --ik-of (draw every IK "
                         "solution of the pose of these joint values)")
    q = _joints_in(robot, args.q if args.q is not None else args.ik_of,
                   "--q" if args.q is not None else "--ik-of", args.deg)
    data = {"robot": robot.name, "out": str(args.out), "joints": _joint_meta(robot, args.deg),
            "q": _jlist(args.q if args.q is not None else args.ik_of), "frames": list(robot.frame_names)}
    if args.q is not None:
        pos = arm_figure(robot, q, args.out, deg=args.deg)
        data["frame_origins"] = {"value": [_jlist(p) for p in pos], "unit": "m"}
        text = f"wrote {args.out}: {robot.name} at q = {_fmt(_joints_out(robot, q, args.deg), 0, 4).strip()}"
    else:
        sols, _ = ik_figure(robot, q, args.out, deg=args.deg)
        data["solutions"] = [_jlist(_joints_out(robot, s, args.deg)) for s in sols]
        text = f"wrote {args.out}: the {len(sols)} IK solution(s) of the pose of {robot.name} at q = " \
               f"{_fmt(_joints_out(robot, q, args.deg), 0, 4).strip()}"
    if args.json:
        _print_json(data)
    else:
        print(text)
    return EXIT_OK


def cmd_path(args) -> int:
    """A Cartesian path (--poses FILE) to a continuous joint path from --seed; CSV, URScript."""
    robot = _robot(args)
    if args.urscript is not None and robot.dof != 6:
        raise InputError(f"path: --urscript drives six-joint arms; {robot.name} has {robot.dof} joints")
    if args.urscript is not None:
        cartesian.check_program_options(args.name, args.accel, args.speed, args.blend)
    seed = _joints_in(robot, args.seed, "--seed", args.deg)
    poses = cartesian.read_poses(args.poses)
    jp = cartesian.path(robot, poses, seed, max_step=args.max_step)
    program = None
    if args.urscript is not None and jp.complete:
        program = cartesian.urscript(jp, name=args.name, accel=args.accel, speed=args.speed, blend=args.blend)
    if args.csv is not None:
        with open(args.csv, "w", encoding="utf-8") as fh:
            fh.write(cartesian.to_csv(jp))
    if program is not None:
        with open(args.urscript, "w", encoding="utf-8") as fh:
            fh.write(program)
    if args.json:
        data = jp.to_dict()
        data["written"] = [f for f in (args.csv, args.urscript if program is not None else None) if f]
        _print_json(data)
    else:
        finite = jp.step[np.isfinite(jp.step)]
        print(f"{robot.name}: {len(jp.q)} poses, {int(jp.found.sum())} configurations"
              + (f", largest joint step {finite.max():.4g} (pose {int(np.nanargmax(jp.step))})" if finite.size else ""))
        for event in jp.events:
            print(event)
        if args.csv is None and args.urscript is None:
            names = list(robot.variable_names)
            print("pose  " + "  ".join(f"{n:>12}" for n in names) + ("  (deg)" if args.deg else "  (rad)"))
            for i, row in enumerate(jp.q):
                print(f"{i:4d}  " + "  ".join(f"{x:12.6f}" for x in _joints_out(robot, row, args.deg)))
        for f in (args.csv, args.urscript if program is not None else None):
            if f:
                print(f"wrote {f}")
    if args.urscript is not None and program is None:
        missing = ", ".join(str(i) for i in np.nonzero(~jp.found)[0][:10])
        print(f"dq-derive: no URScript program written: pose(s) {missing} have no configuration",
              file=sys.stderr)
    return EXIT_OK if jp.complete else EXIT_NO_SOLUTION


def cmd_generate(args) -> int:
    """Regenerate the outputs of the default robots and print an FK table."""
    from derive.codegen.emit import write_kernels
    from derive.ik.program import write_class_data
    from derive.refinement.functions import write_casadi
    from derive.reports.appendix import write_appendix
    from derive.reports.ik_report import write_ik
    t0 = time.perf_counter()
    robots = args.robots or list(DEFAULT_ROBOTS)
    print(f"dq-derive {__version__}: generate for {', '.join(robots)}")
    written = []
    for name in robots:
        t = time.perf_counter()
        paths = write_appendix(name, args.out, progress=True, command=f"dq-derive appendix {name}", force=True)
        paths += write_ik(name, args.out, progress=True, command=f"dq-derive ik {name}", force=True)
        paths += write_kernels(name, args.out, command=f"dq-derive kernels {name}", force=True)
        written += paths
        print(f"{name}: appendix B and C equations and the closed-form IK derived, verified and written in "
              f"{time.perf_counter() - t:.2f} s")
    if not args.robots:
        t = time.perf_counter()
        written.append(write_class_data(args.class_data))
        print(f"the UR and spherical-wrist classes' IK with symbolic lengths derived and written in "
              f"{time.perf_counter() - t:.2f} s")
        # the general 6R derivation's decision of every library arm on that route (shipped, keyed
        # by identity, so a fresh install's `robots` needs no derivation to label them)
        t = time.perf_counter()
        g6_arms = [n for n in list_robots() if "general 6R elimination" in _robot_row(n)["ik"]]
        written.append(general6r.write_decisions(g6_arms, args.general6r_data))
        print(f"the general 6R elimination's decision of {', '.join(g6_arms)} derived and written in "
              f"{time.perf_counter() - t:.2f} s")
        t = time.perf_counter()
        sw = SW_ROBOTS
        name = sw[0]
        written += write_appendix(name, args.out, progress=True, command=f"dq-derive appendix {name}", force=True)
        written += write_ik(name, args.out, progress=True, command=f"dq-derive ik {name}", force=True)
        print(f"{name}: spherical-wrist class equations and closed-form IK written in "
              f"{time.perf_counter() - t:.2f} s")
        t = time.perf_counter()
        for name in UR_ROBOTS + tuple(sw):
            if name not in robots:
                written += write_kernels(name, args.out, command=f"dq-derive kernels {name}", force=True)
            written += write_casadi(name, args.out, force=True)
        print(f"FK/IK kernels and CasADi functions (fk, fk_matrix, pose_error, pose_error_jacobian, "
              f"residual, ik) of {', '.join(UR_ROBOTS + tuple(sw))} written in {time.perf_counter() - t:.2f} s")
        for name in SEVEN_ROBOTS:
            t = time.perf_counter()
            if name in SEVEN_ROBOTS[:2]:
                written += write_appendix(name, args.out, progress=True, command=f"dq-derive appendix {name}",
                                          force=True)
                written += write_ik(name, args.out, progress=True, command=f"dq-derive ik {name}", force=True)
            written += write_kernels(name, args.out, command=f"dq-derive kernels {name}", force=True)
            written += write_casadi(name, args.out, force=True)
            what = "appendix, IK report, " if name in SEVEN_ROBOTS[:2] else ""
            print(f"{name}: seven joints, {what}kernels and CasADi functions with the free parameter "
                  f"written in {time.perf_counter() - t:.2f} s")
    for line in _robots_table([_robot_row(name) for name in list_robots()]):
        print(line)
    print()
    print("Forward kinematics at reference configurations (dual-quaternion product;"
          " max |DQ - matrix| is the gap to the independent 4x4 path):")
    rng = np.random.default_rng(0)
    for name in robots:
        robot = load_robot(name)
        samples = {"zero": np.zeros(robot.dof),
                   "random": rng.uniform(-math.pi, math.pi, robot.dof)}
        for label, q in samples.items():
            gap = np.max(np.abs(dq.to_matrix(reference.fk(robot, q)) - reference.fk_matrix(robot, q)))
            print(f"{name} q={label} ({_fmt(q, 7, 3)} rad), max |DQ - matrix| = {gap:.1e}")
            for line in _pose_lines(reference.fk(robot, q), deg=False):
                print(line)
    _report(written)
    print(f"generate took {time.perf_counter() - t0:.2f} s")
    return EXIT_OK


def cmd_bench(args) -> int:
    from derive.bench.runner import main as bench_main
    argv = [args.what, "--repeats", str(args.repeats)] + (["--robot", args.robot] if args.robot else [])
    argv += (["--json", args.json] if args.json else []) + (["--plot", args.plot] if args.plot else [])
    return bench_main(argv)


# --------------------------------------------------------------------------- #
# reach and place: reachability maps and base placement on Dask (derive.apps.reach)
# --------------------------------------------------------------------------- #
def _reach_tool(args):
    return None if args.tool is None else list(args.tool)


def _reach_interrupted() -> int:
    print("\ndq-derive: interrupted; the chunks written are kept: the same command again resumes",
          file=sys.stderr)
    return 130


def cmd_reach(args) -> int:
    """A reachability map (docs/reach.md) into a Zarr group; the summary on stdout."""
    from derive.apps.plots import reach_figure
    from derive.apps.reach import reach
    try:
        m = reach(_robot(args), args.voxel, args.orientations, args.out, tool=_reach_tool(args),
                  scheduler=args.scheduler, chunk=args.chunk, solutions=args.solutions,
                  free_samples=args.free_samples, max_chunks=args.max_chunks, overwrite=args.overwrite,
                  progress=not args.quiet)
    except KeyboardInterrupt:
        return _reach_interrupted()
    st = m.stats
    r = np.nan_to_num(m.reach)
    if args.plot:
        reach_figure(m, args.plot)
    summary = {"out": str(m.path), "shape": list(m.reach.shape), "origin": m.origin.tolist(), "voxel": m.voxel,
               "orientations": m.orientations, "complete": m.complete, "chunks": st.chunks,
               "computed": st.computed, "ik_calls": st.poses, "seconds": round(st.wall, 3),
               "reachable_voxels": int(np.count_nonzero(r > 0)), "plot": args.plot}
    if args.json:
        print(json.dumps(summary))
        return EXIT_OK
    print(f"{m.attrs['robot']}: {'x'.join(map(str, m.reach.shape))} voxels of {m.voxel:g} m from origin "
          f"{_fmt(m.origin, 4)} m, {m.orientations} orientations each -> {m.path}")
    print(f"chunks: {st.computed} computed now, {st.chunks} in all"
          f"{'' if m.complete else ' (incomplete: run again to resume)'}; {st.poses} IK calls in {st.wall:.2f} s")
    print(f"reachable voxels (fraction > 0): {summary['reachable_voxels']}, fully dexterous (fraction 1): "
          f"{int(np.count_nonzero(r >= 1.0))}")
    if args.plot:
        print(f"figure: {args.plot}")
    return EXIT_OK


def cmd_place(args) -> int:
    """A base-placement map (docs/reach.md) into a Zarr group; the best placements on stdout."""
    from derive.apps.plots import place_figure
    from derive.apps.reach import place
    try:
        p = place(_robot(args), args.targets, args.region, args.step, z=args.z, yaw_steps=args.yaw_steps,
                  out=args.out, tool=_reach_tool(args), scheduler=args.scheduler, chunk=args.chunk,
                  free_samples=args.free_samples, max_chunks=args.max_chunks, overwrite=args.overwrite,
                  progress=not args.quiet)
    except KeyboardInterrupt:
        return _reach_interrupted()
    if args.plot:
        place_figure(p, args.plot, best=args.best)
    best = p.best(args.best)
    if args.json:
        print(json.dumps({"out": str(p.path), "shape": list(p.placement.shape), "complete": p.complete,
                          "targets": len(p.targets), "seconds": round(p.stats.wall, 3), "plot": args.plot,
                          "best": [dict(zip(("x", "y", "z", "yaw", "fraction"), b)) for b in best]}))
        return EXIT_OK
    print(f"{p.attrs['robot']}: {len(p.xs)} x {len(p.ys)} positions x {len(p.yaws)} yaws, {len(p.targets)} "
          f"targets -> {p.path}{'' if p.complete else ' (incomplete: run again to resume)'}")
    print("best placements (base x, y, z in m, yaw in deg, fraction of targets reachable):")
    for n, (x, y, z, yaw, f) in enumerate(best):
        print(f"  {n + 1}. x={x:+.4f} y={y:+.4f} z={z:+.4f} yaw={math.degrees(yaw):7.2f}  {f:.4f}")
    if args.plot:
        print(f"figure: {args.plot}")
    return EXIT_OK


def _reach_commands(command, robot_argument) -> None:
    """The parsers of ``reach`` and ``place``."""
    def common(s, chunk):
        s.add_argument("--out", required=True, metavar="MAP.zarr", help="the Zarr group to write (a stopped run "
                                                                         "resumes from its finished chunks)")
        s.add_argument("--tool", nargs=7, type=float, default=None, metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                       help="a tool transform after the end frame: position (m) and unit quaternion (xyzw)")
        s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="a dask.distributed scheduler (tcp://host:8786), or threads / processes / "
                            "synchronous (default: the local threaded scheduler on every core)")
        s.add_argument("--plot", default=None, metavar="FILE", help="also write the figure (PNG)")
        s.add_argument("--chunk", type=int, default=chunk, help="the edge of a task's block, in grid cells")
        s.add_argument("--free-samples", type=int, default=8, dest="free_samples",
                       help="seven-joint arms: values of the free parameter tried per pose")
        s.add_argument("--max-chunks", type=int, default=None, dest="max_chunks",
                       help="compute at most this many chunks now (run again to resume)")
        s.add_argument("--overwrite", action="store_true", help="replace a map of other parameters at --out")
        s.add_argument("--quiet", action="store_true", help="no progress bar")
        s.add_argument("--json", action="store_true", help="print the summary as JSON")

    s = command("reach", "reachability map: the fraction of N orientations with an IK solution within the "
                         "joint limits at every voxel of the reach, on Dask, into a Zarr group", cmd_reach)
    robot_argument(s)
    s.add_argument("--voxel", type=float, required=True, metavar="S", help="the voxel edge (m)")
    s.add_argument("--orientations", type=int, default=100, metavar="N",
                   help="orientations per voxel (super-Fibonacci spiral over SO(3))")
    s.add_argument("--solutions", action="store_true", help="also store the in-limit solutions per voxel")
    common(s, 32)

    s = command("place", "base placement: the fraction of target poses (CSV x,y,z,qx,qy,qz,qw) reachable "
                         "from every candidate base position and yaw, on Dask, into a Zarr group", cmd_place)
    robot_argument(s)
    s.add_argument("--targets", required=True, metavar="FILE", help="CSV of target poses x,y,z,qx,qy,qz,qw "
                                                                     "(m, unit quaternion) in the world frame")
    s.add_argument("--region", nargs=4, type=float, required=True, metavar=("XMIN", "XMAX", "YMIN", "YMAX"),
                   help="the candidate base positions (m)")
    s.add_argument("--step", type=float, required=True, metavar="S", help="the grid step of the positions (m)")
    s.add_argument("--z", type=float, default=0.0, help="the base's height (m)")
    s.add_argument("--yaw-steps", type=int, default=1, dest="yaw_steps", metavar="K",
                   help="yaws 2 pi k / K about z per position")
    s.add_argument("--best", type=int, default=5, help="how many best placements to print and mark")
    common(s, 8)


# --------------------------------------------------------------------------- #
# The parser
# --------------------------------------------------------------------------- #
class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs as written; an option's default shown where it has a value."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default not in (None, False, argparse.SUPPRESS) and "default" not in text \
                and (action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE)):
            text += " (default: %(default)s)"
        return text


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dq-derive", description=_DESCRIPTION, epilog=_EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"dq-derive {__version__}",
                   help="print the version and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND",
                           help="one of the subcommands below; dq-derive COMMAND --help for its options")

    def command(name, help_text, func, description=None):
        text = description or help_text[:1].upper() + help_text[1:] + "."
        s = sub.add_parser(name, help=help_text, description=textwrap.fill(text, 92),
                           epilog=_EXIT_EPILOG, formatter_class=_Formatter)
        s.set_defaults(func=func)
        return s

    def robot_argument(s):
        s.add_argument("robot", help="library name (dq-derive robots lists them), or path to a description "
                                     "file (.yaml) or a URDF (.urdf)")
        s.add_argument("--base", default=None, help="URDF: the base link of the chain (default: the root link)")
        s.add_argument("--tip", default=None, help="URDF: the tip link of the chain (default: the single leaf link)")

    def json_option(s, what="the results"):
        s.add_argument("--json", action="store_true", help=f"print {what} as JSON (numbers, names, units)")

    def deg_option(s, what="revolute joint values and rpy angles, in and out"):
        s.add_argument("--deg", action="store_true", help=f"degrees instead of radians: {what}")

    def q_option(s, help_text="joint values in joint order (rad, prismatic joints m; --deg: revolute in degrees)",
                 required=False):
        s.add_argument("--q", nargs="+", type=float, default=None, metavar="Q", required=required, help=help_text)

    def target_options(s, with_json=True):
        q_option(s, "target: the pose of these joint values (rad, prismatic joints m; --deg: revolute in degrees)")
        s.add_argument("--xyz", nargs=3, type=float, default=None, metavar=("X", "Y", "Z"),
                       help="target: the end frame's position (m); its orientation from --rpy or --quat")
        s.add_argument("--rpy", nargs=3, type=float, default=None, metavar=("R", "P", "Y"),
                       help="orientation of --xyz: roll, pitch, yaw about the fixed x, y, z axes, "
                            "R = Rz(Y) Ry(P) Rx(R) (rad; --deg: degrees)")
        s.add_argument("--quat", nargs=4, type=float, default=None, metavar=("A", "B", "C", "D"),
                       help="orientation of --xyz: a unit quaternion in the order of --quat-order "
                            "(normalised when its norm is within 1e-4 of 1)")
        s.add_argument("--quat-order", choices=("xyzw", "wxyz"), default=None,
                       help="the order of --quat: xyzw (scipy, ROS) or wxyz (scalar first, as dq-derive); "
                            "required with --quat")
        s.add_argument("--dq", nargs=8, type=float, default=None, metavar="D",
                       help="target: a unit dual quaternion [real w x y z | dual w x y z], dual = 1/2 t real")
        deg_option(s, "revolute joint values (target, seed and output) and rpy angles")
        if with_json:
            json_option(s)

    s = command("robots", "list the robots of the library: kinematic class, closed-form IK, kernels "
                          "and CasADi functions", cmd_robots)
    json_option(s, "the list")

    s = command("fk", "forward kinematics of one configuration: position, rpy, quaternion, dual "
                      "quaternion (and 4x4 matrix) of the end frame", cmd_fk)
    robot_argument(s)
    q_option(s)
    s.add_argument("q_positional", nargs="*", type=float, metavar="Q", default=argparse.SUPPRESS,
                   help="deprecated: the joint values as positional arguments (before or after the "
                        "options); use --q")
    deg_option(s)
    s.add_argument("--end", default=None, help="end frame (default: the robot's default end)")
    s.add_argument("--matrix", action="store_true", help="also print the 4x4 matrix (independent matrix product)")
    json_option(s)

    s = command("classify", "kinematic class: parallel / intersecting axes, spherical wrist, UR / OPW / "
                            "SRS, near misses", cmd_classify)
    robot_argument(s)
    json_option(s, "the classification")

    def emitter(name, help_text, func, quiet=True):
        """A subcommand that writes files for one robot into --out."""
        s = command(name, help_text, func)
        robot_argument(s)
        s.add_argument("--out", default="generated", metavar="DIR",
                       help="output folder" + (" of the typeset IK (without a target)" if name == "ik" else ""))
        if quiet:
            s.add_argument("--quiet", action="store_true", help="no progress output")
        json_option(s, "the results (ik with a target: the solutions; otherwise the written files)"
                    if name == "ik" else "the written files")
        return s

    emitter("appendix", "derive, verify and typeset the M_i = N_i equations (appendix.md, .tex, "
                        "equations.json)", cmd_appendix)

    s = emitter("ik", "inverse kinematics: solve a target (--q, --xyz with --rpy or --quat, --dq) "
                      "in closed form; without a target, extract and typeset the closed-form IK (ik.md, ik.tex)",
                cmd_ik)
    target_options(s, with_json=False)
    s.add_argument("--within-limits", action="store_true",
                   help="every solution inside the joint limits, 2 pi windings included (C kernels)")
    s.add_argument("--seed", nargs="+", type=float, default=None, metavar="Q",
                   help="only the solution nearest to these joint values, within the limits (C kernels; "
                        "--deg: revolute in degrees)")
    s.add_argument("--free", type=float, default=None, metavar="V",
                   help="seven-joint arms: the free parameter, q7 (panda, fr3) or the arm angle psi "
                        "(iiwa7, iiwa14), rad (--deg: degrees); every solution at that value")
    s.add_argument("--free-joint", type=int, default=None, metavar="J", dest="free_joint",
                   help="seven-joint arms: --free V gives joint J's value (J = 1..7; the other six solved "
                        "as a 6R: by a class where one applies, else the general 6R); with --sweep N, N "
                        "values of joint J; with --seed Q, joint J chosen for the path")
    s.add_argument("--sweep", type=int, default=None, metavar="N",
                   help="seven-joint arms: N values of the free parameter over its feasible range, the "
                        "solutions inside the joint limits at each")
    s.add_argument("--pose", nargs="+", type=float, default=None, metavar="Q", dest="pose_old",
                   help="deprecated spelling of --q")

    s = command("refine", "refine IK solutions numerically with CasADi (calibrated or general arms), "
                          "from the nominal closed form or random starts", cmd_refine)
    robot_argument(s)
    target_options(s)
    s.add_argument("--pose", nargs=8, type=float, default=None, metavar="D", dest="pose_old",
                   help="deprecated spelling of --dq")
    s.add_argument("--w-pos", type=float, default=1.0, help="weight of the position error (>= 0)")
    s.add_argument("--w-rot", type=float, default=1.0, help="weight of the rotation error (>= 0)")
    s.add_argument("--reg", type=float, default=0.0, help="regularisation towards the seed (>= 0)")
    s.add_argument("--tol", type=float, default=1e-10, help="success tolerance on both errors (m and rad, > 0)")
    s.add_argument("--max-iter", type=int, default=50, help="iterations per seed (an integer >= 1)")

    s = emitter("kernels", "emit the FK and IK kernels (pure Python, numpy, C99 header and source with a CMake "
                           "package; IK for robots with a closed form)", cmd_kernels, quiet=False)
    s.add_argument("--ikfast", action="store_true",
                   help="also write <robot>_ikfast_solver.cpp, an IKFast 61 drop-in (MoveIt's IKFast plugin; "
                        "docs/ros.md)")

    s = command("export", "write a robot (library, YAML or URDF) as a kinematic URDF or our YAML", cmd_export)
    robot_argument(s)
    s.add_argument("--urdf", default=None, metavar="FILE", help="write a kinematic URDF here")
    s.add_argument("--yaml", default=None, metavar="FILE", help="write a description file (convention urdf) here")
    json_option(s, "the written files")

    s = command("plot", "draw the arm at --q (stick figure, joint axes, frames), or every IK solution of "
                        "the pose of --ik-of side by side, as a PNG", cmd_plot)
    robot_argument(s)
    q_option(s, "draw the arm at these joint values (rad, prismatic joints m; --deg: revolute in degrees)")
    s.add_argument("--ik-of", nargs="+", type=float, default=None, metavar="Q",
                   help="draw every closed-form IK solution of the pose of these joint values")
    s.add_argument("--out", required=True, metavar="FILE", help="the PNG file to write")
    deg_option(s, "revolute joint values (--q, --ik-of) and in the figure's labels")
    json_option(s, "the drawn frame origins or solutions")

    _reach_commands(command, robot_argument)

    s = command("path", "a Cartesian path (poses in a CSV or JSON file) to a continuous joint path, "
                        "each configuration nearest to the previous one; CSV and URScript output", cmd_path)
    robot_argument(s)
    s.add_argument("--poses", required=True, metavar="FILE",
                   help="the poses of the end frame: CSV with the header x,y,z,qx,qy,qz,qw (m, unit "
                        "quaternion in scipy / ROS order), or a JSON list of such rows or objects")
    s.add_argument("--seed", nargs="+", type=float, required=True, metavar="Q",
                   help="the configuration the path starts from (rad, prismatic joints m; --deg: revolute "
                        "in degrees); the first pose's configuration is the one nearest to it")
    s.add_argument("--csv", default=None, metavar="OUT", help="write the joint path here as CSV (rad, m)")
    s.add_argument("--urscript", default=None, metavar="OUT",
                   help="write a URScript program here: one movej per pose (six-joint arms)")
    s.add_argument("--name", default="dq_path", help="the URScript program's name")
    s.add_argument("--speed", type=float, default=cartesian.UR_SPEED,
                   help="URScript movej joint speed v (rad/s)")
    s.add_argument("--accel", type=float, default=cartesian.UR_ACCEL,
                   help="URScript movej joint acceleration a (rad/s^2)")
    s.add_argument("--blend", type=float, default=cartesian.UR_BLEND,
                   help="URScript movej blend radius r (m; 0 stops at every configuration)")
    s.add_argument("--max-step", type=float, default=cartesian.MAX_STEP, dest="max_step",
                   help="report a step larger than this between consecutive configurations (rad, m)")
    deg_option(s, "revolute joint values of --seed and of the printed path (files stay in rad)")
    json_option(s, "the joint path and its events")

    s = command("generate", "regenerate the outputs of the default robots", cmd_generate)
    s.add_argument("robots", nargs="*", help=f"robots (default: {' '.join(DEFAULT_ROBOTS)}, then the "
                                             "spherical-wrist reports and every shipped kernel)")
    s.add_argument("--out", default="generated", help="output folder")
    s.add_argument("--class-data", default=None, metavar="FILE",
                   help="where the 6R classes' symbolic IK goes (default: the package's "
                        "derive/data/ik_classes.json; written when no robots are named)")
    s.add_argument("--general6r-data", default=None, metavar="FILE", dest="general6r_data",
                   help="where the library's general 6R arms' derivation decisions go (default: the "
                        "package's derive/data/general6r.json; written when no robots are named)")

    s = command("bench", "speed measurements (see docs/benchmarks.md)", cmd_bench)
    s.add_argument("what", nargs="?", default="derivation", choices=BENCHES,
                   help="what to measure: derivation time, reference IK and FK, generated kernels against "
                        "other libraries, the quaternion-vs-matrix chain, refine, load latency")
    s.add_argument("--robot", default=None, help="the robot to measure (default: the bench's own choice)")
    s.add_argument("--repeats", type=int, default=5, help="repetitions of each measurement")
    s.add_argument("--json", default=None, metavar="FILE", help="also write the results as JSON to this file")
    s.add_argument("--plot", default=None, metavar="FILE", help="chain: write the figure to this file (PNG)")
    return p


def _parse(parser, argv):
    """The parsed arguments; ``fk``'s deprecated positional joint values may also come after the
    options (``fk ROBOT --base B --tip T 0 0 0 0 0 0``): its subparser parses intermixed
    arguments (argparse cannot do that for a parser with subcommands)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "fk":
        [action] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        fk = action.choices["fk"]
        args = fk.parse_intermixed_args(argv[1:], argparse.Namespace(command="fk"))
        return args
    return parser.parse_args(argv)


def main(argv=None) -> int:
    parser = build_parser()
    args = _parse(parser, argv)            # a usage error exits with 2 (argparse)
    try:
        return args.func(args)
    except DeriveError as exc:
        print(f"dq-derive: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except BrokenPipeError:                # stdout closed early (dq-derive robots | head): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:                 # an output folder or file that cannot be written
        print(f"dq-derive: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_INPUT
