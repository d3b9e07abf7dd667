"""Every axis-aligned configuration of the general 6R vendor arms (each joint a multiple of pi/2,
taken within its limits): are solutions lost without a flag? For each pose the "truth" is the
union, each member checked on the plain 4x4-matrix FK to 1e-10 and merged within 1e-5 rad, of

* a dense multi-start: damped Newton on the product-form chain from ``--starts`` random
  configurations (no elimination);
* ssik's prebuilt module of the arm (native path), each solution carried onto our FK by Newton;
* the reference's solutions at three nearby poses (twists of 1e-6, random poses for the
  elimination) carried back by Newton.

Each method (the numpy reference ``general6r.solve``, the numpy kernels' ``ik_general``, the C
kernels' ``<id>_ik_batch_general`` and, with ``--python N``, the pure-Python kernels on every N-th
pose) is then counted: poses flagged degenerate, poses not flagged where a truth solution is
missing (within 1e-4 rad), and of those where the generating configuration is missing.

    .venv/bin/python benchmarks/bench_general6r_axis_aligned.py [--arms xarm6,crx10ia,jaco2-6dof]
        [--starts 192] [--methods ref,numpy,c] [--python 0]

The truth takes minutes per arm (2304 xArm6 poses: about 2 min on one core).
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import math
import sys
import time

import numpy as np

import derive
from derive import reference
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.codegen.general6r import c_ik_general
from derive.ik import general6r as g

SSIK = {"crx10ia": "ssik.prebuilt.fanuc.crx10ia_ik", "xarm6": "ssik.prebuilt.ufactory.xarm6_ik",
        "jaco2-6dof": "ssik.prebuilt.kinova.jaco2_ik"}


def configurations(robot):
    """Every combination of -pi/2, 0, pi/2, pi per joint (a value or its 2 pi winding within the
    joint's limits; a joint with none of them left out of the product)."""
    per = []
    for lo, hi in robot.limits:
        opts = []
        for v in (-math.pi / 2, 0.0, math.pi / 2, math.pi):
            w = next((w for w in (v, v - 2 * math.pi, v + 2 * math.pi) if lo - 1e-9 <= w <= hi + 1e-9), None)
            if w is not None:
                opts.append(w)
        per.append(opts)
    return np.array(list(itertools.product(*per)))


def _distinct(sols, tol):
    out = []
    for s in sols:
        if not any(np.max(np.abs(wrap_angle(s - o))) < tol for o in out):
            out.append(s)
    return out


def truth(robot, q, starts, seed=0):
    pl = g.plan(robot, progress=False)
    n = len(q)
    P = reference.fk(robot, q)
    T = reference.fk_matrix(robot, q)
    t = T.copy()
    t[:, :3, 3] /= pl.scale
    cands = [[] for _ in range(n)]
    rng = np.random.default_rng(seed)
    for s in range(0, n, 64):
        ip = np.repeat(np.arange(s, min(n, s + 64)), starts)
        qq = rng.uniform(-np.pi, np.pi, (len(ip), 6))
        for _ in range(4):
            qq, err, _ = g._newton(pl.c, qq, t[ip], with_error=True)
        for i, x in zip(ip[err < 1e-11], wrap_angle(qq[err < 1e-11])):
            cands[i].append(x)
    if robot.name in SSIK:
        m = importlib.import_module(SSIK[robot.name])
        for i in range(n):
            for so in m.solve(T[i], native=True):
                cands[i].append(wrap_angle(g._newton(pl.c, np.asarray(so.q, float)[None], t[i:i + 1])[0]))
    tw = np.random.default_rng(99).standard_normal((3, 6))
    tw /= np.linalg.norm(tw, axis=1, keepdims=True)
    for k in range(3):
        moved = g._to_matrix(P)
        axis = np.broadcast_to(tw[k, :3] / np.linalg.norm(tw[k, :3]), (n, 3))
        moved[:, :3, :3] = moved[:, :3, :3] @ quat._to_matrix(quat._from_axis_angle(axis, np.full(n, 1e-6)))
        moved[:, :3, 3] += tw[k, 3:] * 1e-6 * pl.scale
        r = g.solve(robot, moved)
        ip = np.repeat(np.arange(n), r.counts)
        qs = r.q[np.arange(16)[None] < r.counts[:, None]]
        for _ in range(3):
            qs = g._newton(pl.c, qs, t[ip])
        for i, x in zip(ip, wrap_angle(qs)):
            cands[i].append(x)
    out = []
    for i in range(n):
        c = np.array(cands[i]).reshape(-1, 6)
        c = c[np.abs(reference.fk_matrix(robot, c) - T[i]).max(axis=(1, 2)) < 1e-10] if len(c) else c
        out.append(np.array(_distinct(c, 1e-5)).reshape(-1, 6))
    return out


def _c_general(robot, P):
    sols, counts, _, degen = c_ik_general(derive.kernels(robot, "c"), P)
    return sols, counts.astype(int), degen


def solve(robot, method, P):
    if method == "ref":
        r = g.solve(robot, P)
        return r.q, r.counts, r.degenerate
    if method == "numpy":
        s, c, _, d = derive.kernels(robot, "numpy")._mod.ik_general(P)
        return s, c, d
    if method == "c":
        return _c_general(robot, P)
    mod = derive.kernels(robot, "python")._mod
    sols, counts, degen = np.full((len(P), 16, 6), np.nan), np.zeros(len(P), int), np.zeros(len(P), bool)
    for i, p in enumerate(P):
        s, _, d = mod.ik_general(tuple(p))
        s = np.array(s).reshape(-1, 6)
        sols[i, :len(s)], counts[i], degen[i] = s, len(s), bool(d)
    return sols, counts, degen


def _contains(sols, s, tol=1e-4):
    return len(sols) > 0 and float(np.min(np.max(np.abs(wrap_angle(sols - s)), axis=1))) < tol


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arms", default="xarm6,crx10ia,jaco2-6dof")
    ap.add_argument("--starts", type=int, default=192)
    ap.add_argument("--methods", default="ref,numpy,c")
    ap.add_argument("--python", type=int, default=0, help="also the pure-Python kernels on every N-th pose")
    args = ap.parse_args(argv)
    for arm in args.arms.split(","):
        robot = derive.load_robot(arm)
        q = configurations(robot)
        t0 = time.time()
        tr = truth(robot, q, args.starts)
        print(f"{arm}: {len(q)} axis-aligned configurations, truth in {time.time() - t0:.0f} s, solutions per "
              f"pose {np.bincount([len(x) for x in tr]).tolist()}", flush=True)
        P = reference.fk(robot, q)
        methods = [(m, np.arange(len(q))) for m in args.methods.split(",") if m]
        if args.python:
            methods.append(("python", np.arange(0, len(q), args.python)))
        for method, idx in methods:
            t0 = time.time()
            sols, counts, degen = solve(robot, method, P[idx])
            dt = time.time() - t0
            lost = [i for i in range(len(idx)) if not degen[i]
                    and any(not _contains(sols[i, :counts[i]], s) for s in tr[idx[i]])]
            gen = sum(1 for i in lost if not _contains(sols[i, :counts[i]], q[idx[i]]))
            nsol = sum(sum(not _contains(sols[i, :counts[i]], s) for s in tr[idx[i]]) for i in lost)
            print(f"  {method:7s} {len(idx):5d} poses: flagged {int(degen.sum()):5d}, solutions lost unflagged on "
                  f"{len(lost)} poses ({nsol} solutions; generating one missing on {gen}), {dt:.1f} s"
                  + (f"; first: {[int(idx[i]) for i in lost[:8]]}" if lost else ""), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
