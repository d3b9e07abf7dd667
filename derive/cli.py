"""The ``dq-derive`` command line."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from derive import reference
from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.bench.runner import BENCHES
from derive.bench.runner import main as bench_main
from derive.codegen.emit import write_kernels
from derive.codegen.loader import kernels
from derive.errors import DeriveError
from derive.ik.closed_form import classify
from derive.model import export
from derive.model.robot import list_robots, load_robot
from derive.refinement.functions import write_casadi
from derive.refinement.solver import refine
from derive.reports.appendix import write_appendix
from derive.reports.ik_report import write_ik

#: Robots ``dq-derive generate`` (and so ``make generate``) works on by default.
DEFAULT_ROBOTS = ("ur3", "ur5")
#: Robots whose FK/IK kernels and CasADi functions ``dq-derive generate`` writes by default
#: (every UR robot), so that they load without a derivation.
UR_ROBOTS = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e")
#: Spherical-wrist robots whose outputs ``dq-derive generate`` writes by default: appendix, IK
#: report, kernels and CasADi functions of the first, kernels and CasADi functions of the rest.
#: Every other robot of the class gets them on request (``dq-derive kernels ROBOT`` ...).
SW_ROBOTS = ("irb120", "kr6-r900")


def _robot(args):
    """The robot of a subcommand: a library name, a YAML file or a URDF (--base, --tip)."""
    return load_robot(args.robot, base=args.base, tip=args.tip)


def _fmt(values, width=10, prec=6) -> str:
    return " ".join(f"{v:{width}.{prec}f}" for v in np.asarray(values, dtype=float).ravel())


def cmd_robots(args) -> int:
    print(f"{'name':<12} {'dof':>3}  {'convention':<12} {'ends':<28} title")
    for name in list_robots():
        r = load_robot(name)
        ends = ",".join(r.ends)
        print(f"{name:<12} {r.dof:>3}  {r.convention:<12} {ends:<28} {r.title}")
    return 0


def _pose_lines(robot, q, end=None) -> list[str]:
    Q = reference.fk(robot, q, end)
    t = dq._translation(Q)
    yaw, pitch, roll = quat.euler_zyx(Q[:4])
    return [
        f"  dual quaternion [w x y z | w x y z]: {_fmt(Q, 9, 5)}",
        f"  position (m):                        {_fmt(t, 9, 5)}",
        f"  rotation (w x y z):                  {_fmt(Q[:4], 9, 5)}",
        f"  ZYX yaw pitch roll (deg):            "
        f"{_fmt(np.degrees([yaw, pitch, roll]), 9, 3)}",
    ]


def cmd_fk(args) -> int:
    robot = _robot(args)
    q = np.array(args.q, dtype=float)
    if args.deg:
        revolute = [j.type == "revolute" for j in robot.joints if not j.is_mimic]
        if len(revolute) == q.size:
            q = np.where(revolute, np.radians(q), q)
    lines = _pose_lines(robot, q, args.end)
    print(f"{robot.name}: end frame {args.end or robot.default_end!r}, q = {_fmt(q, 8, 4)}")
    for line in lines:
        print(line)
    if args.matrix:
        print("  4x4 matrix (independent matrix product):")
        for row in reference.fk_matrix(robot, q, args.end):
            print("   ", _fmt(row, 10, 6))
    return 0


def cmd_classify(args) -> int:
    """Kinematic class of a robot: consecutive axes, spherical wrist, UR / OPW / SRS."""
    c = classify(_robot(args))
    print(json.dumps(c.to_dict(), indent=2) if args.json else c.report())
    return 0


def _report(paths, t0=None) -> int:
    for p in paths:
        print(f"wrote {p}")
    if t0 is not None:
        print(f"took {time.perf_counter() - t0:.2f} s")
    return 0


def cmd_appendix(args) -> int:
    t0 = time.perf_counter()
    return _report(write_appendix(_robot(args), args.out, progress=not args.quiet), t0)


def cmd_ik(args) -> int:
    t0 = time.perf_counter()
    if args.pose is not None:
        q = np.array(args.pose, dtype=float)
        robot = _robot(args)
        if args.deg:
            q = np.radians(q)
        pose = reference.fk(robot, q)
        if args.seed is not None or args.within_limits:
            return _ik_select(robot, pose, q, args)
        sols = reference.ik(robot, pose, q_ref=q)
        print(f"{robot.name}: pose of q = {_fmt(q, 8, 4)} has {len(sols)} solution(s){sols.reason}")
        for s, sing in zip(sols, sols.singular):
            print("   ", _fmt(s, 9, 5), "(singular: the free wrist joint from q)" if sing else "")
        return 0
    return _report(write_ik(_robot(args), args.out, progress=not args.quiet), t0)


def _ik_select(robot, pose, q, args) -> int:
    """ik --pose Q with --within-limits and/or --seed: the C kernels' selection."""
    k = kernels(robot, "c")
    conv = np.degrees if args.deg else (lambda x: x)
    unit = "deg" if args.deg else "rad"
    if args.seed is not None:
        seed = np.radians(args.seed) if args.deg else np.array(args.seed, dtype=float)
        res = k.nearest(pose, seed)
        if not res.found:
            print(f"{robot.name}: no solution inside the joint limits")
            return 0
        print(f"{robot.name}: solution nearest to the seed (largest joint move "
              f"{conv(res.max_move):.5g} {unit}, summed {conv(res.total_move):.5g} {unit}, branch "
              f"{int(res.branch)}{', singular' if res.singular else ''}):")
        print("   ", _fmt(conv(res.q), 9, 5), f"({unit})")
        return 0
    sols, count, branch, sing = k.ik(pose, within_limits=True, details=True)
    print(f"{robot.name}: {count} solution(s) inside the joint limits, every 2 pi winding ({unit}):")
    for s, b, g in zip(sols[:count], branch[:count], sing[:count]):
        print("   ", _fmt(conv(s), 9, 5), f"branch {int(b)}" + (", singular" if g else ""))
    return 0


def cmd_refine(args) -> int:
    """Refine IK solutions on the robot's model: the pose from --q (FK) or --pose (dual quaternion)."""
    robot = _robot(args)
    if (args.q is None) == (args.pose is None):
        raise DeriveError("refine: give exactly one of --q (joint values whose FK is the pose) "
                          "or --pose (8 numbers, a unit dual quaternion)")
    if args.q is not None:
        q = np.array(args.q, dtype=float)
        pose = reference.fk(robot, np.radians(q) if args.deg else q)
    else:
        pose = np.array(args.pose, dtype=float)
    t0 = time.perf_counter()
    res = refine(robot, pose, weights=(args.w_pos, args.w_rot), regularization=args.reg,
                 tol=args.tol, max_iter=args.max_iter)
    dt = time.perf_counter() - t0
    print(f"{robot.name}: {len(res)} seed(s), {len(res.solutions)} distinct exact solution(s) "
          f"in {dt * 1e3:.1f} ms")
    print(f"{'seed':>4} {'ok':>3} {'iter':>4} {'|dp| (m)':>9} {'angle (rad)':>11}  solver          q (rad)")
    for r in res:
        print(f"{r.seed:4d} {'yes' if r.success else 'no':>3} {r.iterations:4d} {r.position_error:9.1e} "
              f"{r.rotation_error:11.1e}  {r.solver:<15} {_fmt(r.q, 9, 5)}")
    for r in res:
        if r.note:
            print(f"seed {r.seed}: {r.note}")
    if not res.success:
        print(f"no exact solution: best residual {res.best.position_error:.3e} m, "
              f"{res.best.rotation_error:.3e} rad")
    return 0 if res.success else 1


def cmd_export(args) -> int:
    """Write the robot as a kinematic URDF and/or as our YAML (convention urdf)."""
    robot = _robot(args)
    if args.urdf is None and args.yaml is None:
        raise DeriveError("export: give --urdf FILE and/or --yaml FILE")
    return _report(export.write(robot, args.urdf, args.yaml))


def cmd_kernels(args) -> int:
    return _report(write_kernels(_robot(args), args.out))


def cmd_generate(args) -> int:
    """Regenerate the outputs of the default robots and print an FK table."""
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
    cmd_robots(args)
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
            print(f"{name} q={label} ({_fmt(q, 7, 3)}), max |DQ - matrix| = {gap:.1e}")
            for line in _pose_lines(robot, q):
                print(line)
    _report(written)
    print(f"generate took {time.perf_counter() - t0:.2f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dq-derive", description=__doc__)
    p.add_argument("--version", action="version", version=f"dq-derive {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("robots", help="list the robots of the library")
    s.set_defaults(func=cmd_robots)

    def robot_argument(s):
        s.add_argument("robot", help="library name, or path to a description file (.yaml) or URDF (.urdf)")
        s.add_argument("--base", default=None, help="URDF: the base link of the chain (default: the root link)")
        s.add_argument("--tip", default=None, help="URDF: the tip link of the chain (default: the single leaf link)")

    s = sub.add_parser("fk", help="forward kinematics of one configuration")
    robot_argument(s)
    s.add_argument("q", nargs="+", type=float, help="joint values (rad and m unless --deg)")
    s.add_argument("--deg", action="store_true", help="revolute joint values in degrees")
    s.add_argument("--end", default=None, help="end frame (default: the robot's default end)")
    s.add_argument("--matrix", action="store_true", help="also print the 4x4 matrix")
    s.set_defaults(func=cmd_fk)

    s = sub.add_parser("classify", help="kinematic class: parallel / intersecting axes, spherical "
                                        "wrist, UR / OPW / SRS, near misses")
    robot_argument(s)
    s.add_argument("--json", action="store_true", help="print the classification as JSON")
    s.set_defaults(func=cmd_classify)

    def emitter(name, help_text, func, quiet=True):
        """A subcommand that writes files for one robot into --out."""
        s = sub.add_parser(name, help=help_text)
        robot_argument(s)
        s.add_argument("--out", default="generated", help="output folder (default: generated)")
        if quiet:
            s.add_argument("--quiet", action="store_true", help="no progress output")
        s.set_defaults(func=func)
        return s

    emitter("appendix", "derive, verify and typeset the M_i = N_i equations", cmd_appendix)
    s = sub.add_parser("refine", help="refine IK solutions numerically with CasADi (calibrated or "
                                      "general arms), from the nominal closed form or random starts")
    robot_argument(s)
    s.add_argument("--q", nargs="+", type=float, default=None, help="joint values whose FK is the pose")
    s.add_argument("--pose", nargs=8, type=float, default=None, help="the pose as a unit dual quaternion")
    s.add_argument("--deg", action="store_true", help="--q revolute values in degrees")
    s.add_argument("--w-pos", type=float, default=1.0, help="weight of the position error")
    s.add_argument("--w-rot", type=float, default=1.0, help="weight of the rotation error")
    s.add_argument("--reg", type=float, default=0.0, help="regularisation towards the seed")
    s.add_argument("--tol", type=float, default=1e-10, help="success tolerance (m and rad)")
    s.add_argument("--max-iter", type=int, default=50)
    s.set_defaults(func=cmd_refine)
    s = emitter("ik", "extract and typeset the closed-form IK (UR family), or solve the pose of --pose q",
                cmd_ik)
    s.add_argument("--pose", nargs=6, type=float, default=None, metavar="Q",
                   help="instead of typesetting: solve the pose of this configuration")
    s.add_argument("--deg", action="store_true", help="--pose and --seed values (and the output) in degrees")
    s.add_argument("--within-limits", action="store_true",
                   help="with --pose: every solution inside the joint limits, 2 pi windings included (C kernels)")
    s.add_argument("--seed", nargs="+", type=float, default=None, metavar="Q",
                   help="with --pose: only the solution nearest to these joint values (C kernels)")
    emitter("kernels", "emit the FK kernels (pure Python, numpy, C99)", cmd_kernels, quiet=False)

    s = sub.add_parser("export", help="write a robot (library, YAML or URDF) as a kinematic URDF or our YAML")
    robot_argument(s)
    s.add_argument("--urdf", default=None, metavar="FILE", help="write a kinematic URDF here")
    s.add_argument("--yaml", default=None, metavar="FILE", help="write a description file (convention urdf) here")
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("generate", help="regenerate the outputs of the default robots")
    s.add_argument("robots", nargs="*", help=f"robots (default: {' '.join(DEFAULT_ROBOTS)})")
    s.add_argument("--out", default="generated", help="output folder (default: generated)")
    s.set_defaults(func=cmd_generate)

    s = sub.add_parser("bench", help="speed measurements (see docs/benchmarks.md)")
    s.add_argument("what", nargs="?", default="derivation", choices=BENCHES)
    s.add_argument("--robot", default=None)
    s.add_argument("--repeats", type=int, default=5)
    s.add_argument("--json", default=None, help="also write the results as JSON to this file")
    s.add_argument("--plot", default=None, help="chain: write the figure to this file (PNG)")
    s.set_defaults(func=cmd_bench)
    return p


def cmd_bench(args) -> int:
    argv = [args.what, "--repeats", str(args.repeats)] + (["--robot", args.robot] if args.robot else [])
    argv += (["--json", args.json] if args.json else []) + (["--plot", args.plot] if args.plot else [])
    return bench_main(argv)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except DeriveError as exc:
        print(f"dq-derive: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:                 # an output folder or file that cannot be written
        print(f"dq-derive: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
