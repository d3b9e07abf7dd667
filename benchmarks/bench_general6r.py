"""The general 6R numpy reference (derive.ik.general6r) against ssik's general solver on the same
poses, in the same run: time per pose and the distribution of solution counts, per arm.

    .venv/bin/python benchmarks/bench_general6r.py [--poses N] [--ssik-poses M] [--seed S]

Arms: the library's general-6r (ssik: ``Manipulator.from_dh`` on its DH numbers, ssik's default
path; its first solve of a new arm derives for minutes, then its cache keeps it) and the Fanuc
CRX-10iA as ssik.prebuilt bakes it (ssik: the prebuilt module's Python and native solve; ours
through the loop cut at joint 2). Needs ssik (pip install ssik).
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

import derive
from derive import reference
from derive.algebra.angles import wrap_angle
from derive.errors import DeriveError
from derive.ik import general6r


def distinct(sols, tol=1e-6):
    out = []
    for s in sols:
        if not any(np.all(np.abs(wrap_angle(s - u)) < tol) for u in out):
            out.append(s)
    return out


def dist_line(counts):
    c = np.bincount(np.asarray(counts, dtype=int), minlength=17)
    return " ".join(f"{k}:{v}" for k, v in enumerate(c) if v)


def crx_robot(folder):
    m = importlib.import_module("ssik.prebuilt.fanuc.crx10ia_ik")
    joints = [{"name": f"j{i + 1}", "origin": {"translation": m._JOINT_T_LEFTS[i][:3, 3].tolist()},
               "axis": np.asarray(m._JOINT_AXES[i], float).tolist(),
               "limits": [float(v) for v in m._JOINT_LIMITS[i]]} for i in range(6)]
    path = Path(folder) / "ssik-crx-geometry.yaml"
    path.write_text(yaml.safe_dump({"name": "ssik-crx-geometry", "convention": "urdf", "joints": joints,
                                    "tool": {"translation": m._JOINT_T_RIGHTS[5][:3, 3].tolist()}}))
    return derive.load_robot(str(path)), m


def ours(robot, q):
    P = reference.fk(robot, q)
    try:
        t0 = time.perf_counter()
        general6r.plan(robot)
        t_plan = time.perf_counter() - t0
    except DeriveError as exc:
        print(f"  dq-derive general6r: not solved: {exc}")
        return None
    general6r.solve(robot, P[:50])                       # warm
    t0, c0 = time.perf_counter(), time.process_time()
    res = general6r.solve(robot, P)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(f"  dq-derive general6r (numpy): {dt / len(q) * 1e6:.0f} us/pose wall, {dc / len(q) * 1e6:.0f} us/pose "
          f"CPU over {len(q)} poses (plan {t_plan:.2f} s: derivation or cache)")
    print(f"    counts: {dist_line(res.counts)}")
    return res


def ssik_line(label, solve, T, robot, res):
    counts, missing = [], 0
    t0, c0 = time.perf_counter(), time.process_time()
    found = [solve(x) for x in T]
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    for i, sols in enumerate(found):
        qs = distinct([np.asarray(s.q, float) for s in sols])
        counts.append(len(qs))
        if res is not None:
            mine = res.q[i, :res.counts[i]]
            missing += sum(not np.any(np.all(np.abs(wrap_angle(mine - s)) < 1e-6, axis=1)) for s in qs)
    extra = "" if res is None else f"; ssik solutions missing from ours: {missing}"
    print(f"  ssik {label}: {dt / len(T) * 1e3:.2f} ms/pose wall, {dc / len(T) * 1e3:.2f} ms/pose CPU over "
          f"{len(T)} poses{extra}")
    print(f"    counts: {dist_line(counts)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--ssik-poses", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    import ssik
    print(f"dq-derive {derive.__version__}, ssik {ssik.__version__}, numpy {np.__version__}")
    a24 = np.random.default_rng(0).standard_normal((2000, 24, 24))
    c0 = time.process_time()
    np.linalg.eigvals(a24)
    print(f"load calibration: numpy eigvals of a random 24 x 24: {(time.process_time() - c0) / 2000 * 1e6:.0f} us CPU")
    rng = np.random.default_rng(a.seed)

    print("general-6r (derive/robots/general-6r.yaml)")
    robot = derive.load_robot("general-6r")
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    q = rng.uniform(lo, hi, (a.poses, 6))
    res = ours(robot, q)
    d = yaml.safe_load(open(robot.path))
    arm = ssik.Manipulator.from_dh([j["alpha"] for j in d["joints"]], [j["a"] for j in d["joints"]],
                                   [j["d"] for j in d["joints"]])
    T = reference.fk_matrix(robot, q[:a.ssik_poses])
    arm.solve(T[0])                                      # derivation / cache load
    ssik_line("Manipulator.from_dh(...).solve (default path)", arm.solve, T, robot, res)

    with tempfile.TemporaryDirectory() as tmp:
        print("Fanuc CRX-10iA (ssik.prebuilt.fanuc.crx10ia_ik geometry)")
        robot, m = crx_robot(tmp)
        lo, hi = robot.limits[:, 0], robot.limits[:, 1]
        q = rng.uniform(lo, hi, (a.poses, 6))
        res = ours(robot, q)
        T = reference.fk_matrix(robot, q[:a.ssik_poses])
        m.solve(T[0])
        ssik_line("prebuilt solve, native=False (Python)", lambda x: m.solve(x, native=False), T, robot, res)
        ssik_line("prebuilt solve, native=True (C++)", lambda x: m.solve(x, native=True), T, robot, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
