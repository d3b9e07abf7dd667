"""Seven-joint arms with joint K given (derive.ik.free_joint): per arm and K, on configurations
drawn within the joint limits with the generating value of joint K given: the route taken,
the solution counts, how often the generating configuration is found, the largest FK error
(4x4 matrix FK, m / entry), the degenerate flags, and the CPU time per pose (numpy, batched).
With ``--ssik M``: on the first M poses of xarm7 and gen3, ssik's joint-lock solver
(ssik.solvers.jointlock.seven_r, same held value) and whether its solutions are all ours.
With ``--c``: the C kernel (derive.codegen.free_joint.c_library, batched, one thread; compiled
before timing: on the SRS class routes the class's IK program, where the numpy column is the same
closed form; on the Panda's q7 the Panda class's kernels, ``derive.kernels(robot, "c")``, which
``free="q7"`` returns; on the general route the general elimination, wherever it has a plan) on the
same poses and values: its CPU time per pose and value (the calling thread's)
(best of ``--repeats``), and on how many poses its solution set equals the numpy reference's.

    .venv/bin/python benchmarks/bench_free_joint.py [--poses N] [--arms a,b] [--joints 1,2] [--ssik M]
        [--c] [--repeats R] [--seed S]
"""

from __future__ import annotations

import argparse
import importlib
import math
import time

import numpy as np

import derive
from derive import reference
from derive.errors import DeriveError, InputError
from derive.ik import free_joint

SSIK = {"xarm7": "ssik.prebuilt.ufactory.xarm7_ik", "gen3": "ssik.prebuilt.kinova.gen3_ik"}


def _wrapped(d):
    return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)


def _same(a, b, tol=1e-6):
    """Whether two solution sets (k, 7) are equal within tol in every joint (modulo 2 pi)."""
    if len(a) != len(b):
        return False
    if not len(a):
        return True
    d = _wrapped(a[:, None] - b[None]).max(-1)
    return bool(np.all(d.min(1) < tol) and np.all(d.min(0) < tol))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--arms", default="xarm7,gen3,iiwa14,panda,fr3")
    ap.add_argument("--ssik", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--joints", default="1,2,3,4,5,6,7")
    ap.add_argument("--c", action="store_true", help="time the C kernel on the general route too")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print("| arm | K | route | found | largest FK error | counts (k: share) | degenerate | ms / pose | ssik |"
          + (" C us / pose | C = numpy | C vs numpy |" if args.c else ""))
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |" + (" --- | --- | --- |" if args.c else ""))
    for name in args.arms.split(","):
        robot = derive.load_robot(name)
        lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
        rng = np.random.default_rng(args.seed)
        q = rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (args.poses, 7))
        poses = reference.fk(robot, q)
        target = reference.fk_matrix(robot, q)
        for k in (int(j) for j in args.joints.split(",")):
            try:
                how = free_joint.route(robot, k)
            except InputError:
                print(f"| {name} | {k} | refused | | | | | | |")
                continue
            free_joint.solve(robot, poses[:2], k, q[:2, k - 1])          # plan, caches
            t = time.process_time()          # CPU time (one thread): less sensitive to a loaded machine
            r = free_joint.solve(robot, poses, k, q[:, k - 1])
            dt = (time.process_time() - t) / args.poses * 1e3
            valid = np.arange(r.q.shape[1])[None] < r.counts[:, None]
            rows = np.nonzero(valid)[0]
            err = float(np.abs(reference.fk_matrix(robot, r.q[valid]) - target[rows]).max()) if len(rows) else 0.0
            gen = np.nanmin(np.where(valid, _wrapped(r.q - q[:, None]).max(-1), np.inf), axis=1)
            found = int(np.sum(gen < 1e-6))
            cnt = np.bincount(r.counts)
            dist = ", ".join(f"{c}: {100 * v / args.poses:.1f} %" for c, v in enumerate(cnt) if v)
            extra = ""
            if args.ssik and name in SSIK:
                from ssik.solvers.jointlock import seven_r
                arm = importlib.import_module(SSIK[name])
                theirs = missing = 0
                t0 = time.perf_counter()
                for i in range(min(args.ssik, args.poses)):
                    sols, _ = seven_r.solve(arm._KB, target[i], lock_samples=[q[i, k - 1]], lock_idx=k - 1,
                                            allow_refinement=True)
                    for s in sols:
                        x = np.asarray(s.q, dtype=float)
                        if np.abs(arm.fk(x) - target[i]).max() > 1e-8:
                            continue
                        theirs += 1
                        missing += int(_wrapped(r.q[i, :r.counts[i]] - x).max(-1).min() >= 1e-6)
                ms = (time.perf_counter() - t0) / min(args.ssik, args.poses) * 1e3
                extra = f"{theirs} solutions, {missing} not ours, {ms:.0f} ms / pose"
            ctext = ""
            if args.c:
                ctext = " | | |"
                try:
                    if how == "general":
                        free_joint.plan(robot, k)      # the general elimination; the class routes: their program
                except DeriveError:
                    pass
                else:
                    if how == "panda":     # the user's C with q7 given: the Panda class's kernels
                        kc = derive.kernels(robot, "c")
                        solve = lambda p, v: kc.ik(p, free=v)       # noqa: E731
                    else:
                        from derive.codegen.free_joint import c_library
                        from derive.codegen.loader import _compile
                        lib = c_library(robot, k, _compile)
                        solve = lambda p, v: lib.solve(p, v)[:2]    # noqa: E731
                    times = []
                    for _ in range(max(args.repeats, 1)):
                        # the calling thread's CPU time: the C runs in it, and the process's
                        # would count BLAS threads still spinning after the numpy solves above
                        t0 = time.thread_time()
                        cq, cc = solve(poses, q[:, k - 1])
                        times.append(time.thread_time() - t0)
                    us = min(times) / args.poses * 1e6
                    same = sum(_same(cq[i, :cc[i]], r.q[i, :r.counts[i]]) for i in range(args.poses))
                    ctext = f" {us:.3g} | {same}/{args.poses} | {dt * 1e3 / us:.2g}x |"
            print(f"| {name} | {k} | {how} | {found}/{args.poses} | {err:.1e} | {dist} | "
                  f"{int(r.degenerate.sum())} | {dt:.2f} | {extra} |" + ctext, flush=True)


if __name__ == "__main__":
    main()
