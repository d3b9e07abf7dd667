"""The degenerate flag of the seven-joint free-joint C kernel (templates/free_joint.c.j2) and of
the numpy general route (derive.ik.free_joint._general): per arm and K, on configurations drawn
within the joint limits (``--near``: with |q4| < 0.005, near the SRS elbow singularity) with the
generating value of joint K given: how many poses the C kernel flags, on how many its solution
set differs from free_joint.solve's (the class's closed form on the class routes, the numpy
general elimination on the general route; every joint within 1e-6 rad), how many of those are
not flagged (the project's rule: never silently incomplete, so 0), and how many the numpy
reference flags.

    .venv/bin/python benchmarks/bench_free_joint_flags.py ARM K[,K...] [--near] [--poses N]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

import derive
from derive import reference
from derive.codegen import free_joint as cfree
from derive.codegen.loader import _compile
from derive.ik import free_joint

from bench_free_joint import _same      # the set comparison of the timing benchmark (same folder)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("arm")
    ap.add_argument("joints")
    ap.add_argument("--near", action="store_true")
    ap.add_argument("--poses", type=int, default=1000)
    a = ap.parse_args()
    robot = derive.load_robot(a.arm)
    n = a.poses
    lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
    for k in [int(x) for x in a.joints.split(",")]:
        lib = cfree.c_library(robot, k, _compile)
        rng = np.random.default_rng(1000 + k)
        q = rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (n, 7))
        if a.near:
            q[:, 3] = rng.uniform(-0.005, 0.005, n)
        v = q[:, k - 1]
        poses = reference.fk(robot, q)
        cq, cc, _, flag = lib.solve(poses, v)
        ref = free_joint.solve(robot, poses, k, v)
        differ = np.array([not _same(cq[i, :cc[i]], ref.q[i, :ref.counts[i]]) for i in range(n)])
        print(f"{a.arm} q{k} ({free_joint.route(robot, k)}) {'|q4| < 0.005' if a.near else 'random'}, {n} poses: "
              f"C flagged {flag.sum()} ({100 * flag.mean():.2f} %), C set != reference {differ.sum()}, "
              f"of them unflagged {(differ & ~flag).sum()}; numpy reference flagged {ref.degenerate.sum()}", flush=True)


if __name__ == "__main__":
    main()
