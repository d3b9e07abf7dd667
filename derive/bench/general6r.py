"""Speed of the general 6R kernels (``dq-derive bench kernels --robot crx10ia``): the C batch IK,
the numpy kernels and the numpy reference (:func:`derive.ik.general6r.solve`) on the same poses,
the one-call latency of the C and numpy kernels (one pose per call from Python through the loaded
kernels, as the closed-form classes' benchmark measures it), and ssik's solver of the same arm
where ssik ships one (``ssik.prebuilt``; its FK equals ours, tests/test_vendor_arms.py), with the
solution counts of each."""

from __future__ import annotations

import importlib
import importlib.util
import time

import numpy as np

from derive import reference
from derive.bench.machine import best_time as _time
from derive.bench.machine import machine
from derive.codegen.loader import c_flags, kernels
from derive.ik import general6r
from derive.model.robot import load_robot

#: ssik's prebuilt module of a library arm (FK_ours = FK_ssik, no base or tool transform).
SSIK_MODULES = {"crx10ia": "ssik.prebuilt.fanuc.crx10ia_ik", "xarm6": "ssik.prebuilt.ufactory.xarm6_ik"}


def is_general(robot) -> bool:
    """Whether the robot's C kernels are the general 6R ones (their manifest says so)."""
    k = kernels(robot, "c")
    return k._manifest.get("ik") == "general6r"


def bench_general(robot: str, n: int = 2000, repeats: int = 3, seed: int = 0, n_peer: int = 200,
                  n_single: int = 200) -> dict:
    """Per pose times (us) of the C batch IK (n poses), the numpy kernels and the numpy reference
    (n // 4 poses), the one-call latency of the C and numpy kernels (``k.ik(pose)`` for each of
    n_single poses, the best of ``repeats`` loops for C, one loop for numpy) and ssik (native, one
    call per pose, n_peer poses), configurations uniform within the limits (at most one turn), and
    the mean solution count of each on the same poses."""
    r = load_robot(robot)
    rng = np.random.default_rng(seed)
    lo = np.maximum(r.limits[:, 0], -np.pi)
    hi = np.minimum(r.limits[:, 1], np.pi)
    q = rng.uniform(lo, hi, (n, 6))
    poses = reference.fk(r, q)
    out: dict = {"kind": "general6r", "robot": r.name, "n": n, "machine": machine(),
                 "date": time.strftime("%Y-%m-%d"), "flags": " ".join(c_flags())}
    k = kernels(r, "c")
    k.ik(poses[:4])
    sols, counts = k.ik(poses)
    out["c"] = {"ik_batch_us": _time(lambda: k.ik(poses), repeats) / n * 1e6, "mean_count": float(counts.mean())}
    s = min(n_single, n)
    out["c"]["ik_single_us"] = _time(lambda: [k.ik(row) for row in poses[:s]], repeats) / s * 1e6
    out["c"]["n_single"] = s
    m = max(1, n // 4)
    kn = kernels(r, "numpy")
    kn.ik(poses[:4])
    out["numpy"] = {"ik_batch_us": _time(lambda: kn.ik(poses[:m]), 1) / m * 1e6, "n": m}
    s1 = max(1, min(n_single, m) // 4)
    out["numpy"]["ik_single_us"] = _time(lambda: [kn.ik(row) for row in poses[:s1]], 1) / s1 * 1e6
    out["numpy"]["n_single"] = s1
    general6r.solve(r, poses[:4])
    out["reference"] = {"ik_batch_us": _time(lambda: general6r.solve(r, poses[:m]), 1) / m * 1e6, "n": m}
    name = SSIK_MODULES.get(r.name)
    if name and importlib.util.find_spec("ssik") is not None:
        mod = importlib.import_module(name)
        mats = reference.fk_matrix(r, q[:n_peer])
        mod.solve(mats[0], native=True)
        found = []
        t0 = time.perf_counter()
        for mat in mats:
            found.append(len(mod.solve(mat, native=True)))
        t = (time.perf_counter() - t0) / len(mats)
        out["ssik"] = {"native_us": t * 1e6, "n": len(mats), "mean_count_with_windings": float(np.mean(found)),
                       "c_speedup": t * 1e6 / out["c"]["ik_batch_us"]}
    return out


def general_report(r: dict) -> str:
    lines = [f"general 6R kernels of {r['robot']}, {r['n']} poses within the limits, {r['machine']}, {r['date']}",
             f"C flags: {r['flags']}",
             f"  C batch IK          {r['c']['ik_batch_us']:10.1f} us per pose  ({r['c']['mean_count']:.2f} solutions per pose)",
             f"  C one call          {r['c']['ik_single_us']:10.1f} us per call  (k.ik(pose) from Python, "
             f"{r['c']['n_single']} poses)",
             f"  numpy kernels       {r['numpy']['ik_batch_us']:10.1f} us per pose  ({r['numpy']['n']} poses)",
             f"  numpy one call      {r['numpy']['ik_single_us']:10.1f} us per call  (k.ik(pose) from Python, "
             f"{r['numpy']['n_single']} poses)",
             f"  numpy reference     {r['reference']['ik_batch_us']:10.1f} us per pose  ({r['reference']['n']} poses)"]
    if "ssik" in r:
        s = r["ssik"]
        lines.append(f"  ssik native         {s['native_us']:10.1f} us per pose  ({s['n']} poses, "
                     f"{s['mean_count_with_windings']:.2f} solutions per pose with windings); "
                     f"C is {s['c_speedup']:.1f}x faster")
    return "\n".join(lines)
