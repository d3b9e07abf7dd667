"""The C kernels of the SRS class routes (joint K in {1, 2, 5, 6, 7} given: the class's IK program,
derive.codegen.free_joint.program_source) on 10^4 configurations per arm within the limits, the
configurations of bench_free_joint.py (seed 1), the generating value of joint K given: how often
the C solutions hold the generating configuration (every joint within 1e-6 rad; the worst
distance and its q4), the largest 4x4 matrix-FK error of a C solution, on how many poses the
counts, branch ids and singular flags equal the numpy closed form's (free_joint.solve) and the
values are within 1e-6 rad (the largest difference).

    .venv/bin/python benchmarks/bench_free_joint_srs_c.py iiwa14,iiwa7
"""
import math, sys
import numpy as np
import derive
from derive import reference
from derive.codegen import free_joint as cfree
from derive.codegen.loader import _compile
from derive.ik import free_joint
def w(d): return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)
n = 10000
for name in sys.argv[1].split(","):
    robot = derive.load_robot(name)
    lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
    rng = np.random.default_rng(1)
    q = rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (n, 7))
    poses = reference.fk(robot, q)
    target = reference.fk_matrix(robot, q)
    for k in (1, 2, 5, 6, 7):
        cq, cc, cb, cs = cfree.c_library(robot, k, _compile).details(poses, q[:, k - 1])
        ref = free_joint.solve(robot, poses, k, q[:, k - 1])
        valid = np.arange(16)[None] < cc[:, None]
        rows = np.nonzero(valid)[0]
        err = np.abs(reference.fk_matrix(robot, cq[valid]) - target[rows]).max()
        gen = np.nanmin(np.where(valid, w(cq - q[:, None]).max(-1), np.inf), axis=1)
        same = (cc == ref.counts) & np.all(cb[:, :8] == ref.branch, 1) & np.all(cs[:, :8] == ref.singular, 1)
        d = np.where(valid[:, :8, None], w(cq[:, :8] - np.nan_to_num(ref.q)), 0).max((1, 2))
        print(f"{name} q{k}: found {np.sum(gen < 1e-6)}/{n} (worst {gen.max():.1e} at q4 = {q[np.argmax(gen), 3]:.1e}), "
              f"FK err {err:.1e}, counts/branch/flags equal {same.sum()}, values within 1e-6 {np.sum(d < 1e-6)} "
              f"(largest {d.max():.1e}), singular {cs.sum()}")
