"""Issue 31's accuracy targets for the general 6R numpy reference (derive.ik.general6r), per arm,
on configurations within the limits: every returned solution's FK (plain 4x4 matrices,
reference.fk_matrix) within 1e-10 of the pose, the generating configuration among them, the set
containing every solution of ssik's prebuilt module of the arm (native path), and the
distribution of solution counts; then the CRX's axis-aligned configurations (joints in multiples
of pi/2).

    .venv/bin/python benchmarks/bench_general6r_accuracy.py [--poses 10000] [--ssik-poses 1000]

Times are CPU time of this process (time.process_time), the same measure as
benchmarks/bench_general6r.py.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import time

import numpy as np

import derive
from derive import reference
from derive.algebra.angles import wrap_angle
from derive.ik import general6r

ARMS = {
    "general-6r": (None, None),
    "crx10ia": ("ssik.prebuilt.fanuc.crx10ia_ik", 1e-6),
    "xarm6": ("ssik.prebuilt.ufactory.xarm6_ik", 1e-6),
    # ssik's JACO 2 is built from Kinova's DH table, 1e-7 off the URDF our file transcribes
    "jaco2-6dof": ("ssik.prebuilt.kinova.jaco2_ik", 1e-4),
}


def within_limits(robot, n, seed):
    lim = robot.limits
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -math.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], math.pi)
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, 6))


def contains(sols, q, tol):
    return len(sols) > 0 and bool(np.any(np.all(np.abs(wrap_angle(sols - q)) < tol, axis=1)))


def polished(robot, q, T):
    """ssik's solution q (6,) of the matrix pose T carried onto our arm's FK by Newton (ssik's JACO 2
    is built from Kinova's DH table, 1e-7 off our URDF transcription; near a singularity that moves
    the solution by more than the containment tolerance)."""
    c, scale = general6r.chain_form(robot)
    t = T.copy()
    t[:3, 3] /= scale
    return wrap_angle(general6r._newton(c, q[None], t[None])[0])


def fk_error(robot, res, q):
    """Largest entry of FK(solution) - FK(q) over all solutions (4x4 matrices, m and 1)."""
    worst = 0.0
    target = reference.fk_matrix(robot, q)
    rows = np.repeat(np.arange(len(q)), res.counts)
    sols = res.q[np.arange(16)[None, :] < res.counts[:, None]]
    for s in range(0, len(rows), 20000):
        fkm = reference.fk_matrix(robot, sols[s:s + 20000])
        worst = max(worst, float(np.abs(fkm - target[rows[s:s + 20000]]).max()))
    return worst


def regular_mask(robot, q):
    c, _ = general6r.chain_form(robot)
    frames, end = general6r._chain_frames(c, q)
    axes = frames[:, :, :3, 2]
    jac = np.concatenate([np.cross(axes, end[:, None, :3, 3] - frames[:, :, :3, 3]), axes], 2)
    sv = np.linalg.svd(jac, compute_uv=False)
    return sv[:, -1] > 1e-8 * sv[:, 0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=10000)
    ap.add_argument("--ssik-poses", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=31)
    a = ap.parse_args(argv)
    print(f"dq-derive {derive.__version__}, numpy {np.__version__}")
    for name, (module, tol) in ARMS.items():
        robot = derive.load_robot(name)
        general6r.plan(robot)
        q = within_limits(robot, a.poses, a.seed)
        P = reference.fk(robot, q)
        t0 = time.process_time()
        res = general6r.solve(robot, P)
        dt = time.process_time() - t0
        found = np.array([contains(res.q[i, :res.counts[i]], q[i], 1e-6) for i in range(len(q))])
        dist = np.bincount(res.counts, minlength=17)
        print(f"{name}: {len(q)} configurations within the limits, {dt / len(q) * 1e6:.0f} us/pose (CPU)")
        print(f"  counts: " + " ".join(f"{k}:{v}" for k, v in enumerate(dist) if v)
              + "   (" + " ".join(f"{k}:{100 * v / len(q):.1f}%" for k, v in enumerate(dist) if v) + ")")
        print(f"  largest FK error of a returned solution: {fk_error(robot, res, q):.1e}")
        print(f"  generating configuration among the solutions: {found.sum()}/{len(q)}; "
              f"degenerate poses: {int(res.degenerate.sum())}")
        if module is None:
            continue
        m = importlib.import_module(module)
        n = min(a.ssik_poses, len(q))
        T = reference.fk_matrix(robot, q[:n])
        total = missing = missing_polished = 0
        t0 = time.process_time()
        out = [m.solve(T[i], native=True) for i in range(n)]
        t_ssik = time.process_time() - t0
        for i, sols in enumerate(out):
            for s in sols:
                total += 1
                sq = np.asarray(s.q, float)
                missing += not contains(res.q[i, :res.counts[i]], sq, tol)
                missing_polished += not contains(res.q[i, :res.counts[i]], polished(robot, sq, T[i]), 1e-6)
        print(f"  ssik ({module}, native): {total} solutions on {n} poses, missing from ours: {missing} "
              f"(tolerance {tol:g} rad), {missing_polished} after Newton onto our FK (tolerance 1e-6 rad); "
              f"ssik {t_ssik / n * 1e3:.2f} ms/pose (CPU)")

    robot = derive.load_robot("crx10ia")
    vals = np.array([-math.pi / 2, 0.0, math.pi / 2, math.pi])
    q = vals[np.random.default_rng(a.seed).integers(0, 4, (400, 6))]
    res = general6r.solve(robot, reference.fk(robot, q))
    reg = regular_mask(robot, q)
    found = np.array([contains(res.q[i, :res.counts[i]], q[i], 1e-6) for i in range(len(q))])
    near = np.array([contains(res.q[i, :res.counts[i]], q[i], 1e-4) for i in range(len(q))])
    print("crx10ia, 400 axis-aligned configurations (joints in multiples of pi/2):")
    print(f"  regular {reg.sum()}: generating configuration found {np.sum(reg & found)}")
    print(f"  singular {np.sum(~reg)}: found within 1e-6 rad {np.sum(~reg & found)}, within 1e-4 rad "
          f"{np.sum(~reg & near)}, flagged degenerate {np.sum(~reg & res.degenerate)}, neither found "
          f"within 1e-4 nor flagged {np.sum(~reg & ~near & ~res.degenerate)}")
    print(f"  largest FK error of a returned solution: {fk_error(robot, res, q):.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
