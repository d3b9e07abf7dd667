"""Speed measurements (``dq-derive bench``). Not tests: numbers go to docs/benchmarks.md."""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from derive import reference
from derive.bench import BENCHES
from derive.bench.chain import bench_chain_c, bench_chain_numpy, op_counts, plot
from derive.bench.kernels import bench_kernels, report
from derive.bench.load import bench_load
from derive.bench.load import report as load_report
from derive.bench.machine import machine
from derive.codegen.loader import kernels
from derive.refinement.solver import refine

_DERIVATION_RUN = r"""
import json, sys, time
t0 = time.perf_counter()
import derive.reports.appendix
t1 = time.perf_counter()
derive.reports.appendix.write_appendix(sys.argv[1], sys.argv[2])
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "derive_verify_emit_s": t2 - t1}))
"""


def bench_derivation(robot: str = "ur3", repeats: int = 5) -> dict:
    """Whole derivation, simplification, verification and emission, each run in a fresh process."""
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            t = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", _DERIVATION_RUN, robot, tmp],
                                 capture_output=True, text=True, check=True)
            wall = time.perf_counter() - t
            r = json.loads(res.stdout.strip().splitlines()[-1])
            r["process_wall_s"] = wall
            runs.append(r)
    keys = ("import_s", "derive_verify_emit_s", "process_wall_s")
    return {"robot": robot, "repeats": repeats, "machine": machine(),
            **{f"median_{k}": statistics.median(r[k] for r in runs) for k in keys},
            **{f"max_{k}": max(r[k] for r in runs) for k in keys}}


def bench_ik(robot: str = "ur5", n: int = 100_000, single: int = 2000, seed: int = 0) -> dict:
    """Reference IK (numpy): time per pose on a batch of n poses, and per single call."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, size=(n, 6))
    poses = reference.fk(robot, q)
    reference.ik_batch(robot, poses[:100])                     # warm-up (chain extraction)
    t = time.perf_counter()
    _, counts = reference.ik_batch(robot, poses)
    batch = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for p in poses[:single]:
        reference.ik(robot, p)
    one = (time.perf_counter() - t) / single
    return {"robot": robot, "n": n, "machine": machine(), "batch_us": batch * 1e6,
            "single_us": one * 1e6, "mean_solutions": float(counts.mean())}


def bench_fk(robot: str = "ur5", n: int = 100_000, seed: int = 0) -> dict:
    """Generated FK kernels: ns per pose on a batch of n poses, for each backend."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(n, 6))
    out = {"robot": robot, "n": n, "machine": machine()}
    for backend, count in (("c", n), ("numpy", n), ("python", n // 10)):
        k = kernels(robot, backend)
        k.fk(q[:10])
        t = time.perf_counter()
        k.fk(q[:count])
        out[backend] = (time.perf_counter() - t) / count * 1e9
    return out


def bench_refine(n: int = 300, seed: int = 0) -> dict:
    """derive.refine on random reachable poses: the calibrated UR5 from its nominal closed-form
    seeds, the general 6R from 16 random starts."""
    rng = np.random.default_rng(seed)
    out = {"machine": machine(), "date": time.strftime("%Y-%m-%d"), "robots": {}}
    for name, kind, m in (("ur5-calibrated", "nominal closed form", n), ("general-6r", "16 random starts", n // 3)):
        q = rng.uniform(-np.pi, np.pi, size=(m, 6))
        poses = reference.fk(name, q)
        refine(name, poses[0])                                # build the CasADi functions once
        per_seed, per_conv, iters, per_pose, per_sol = [], [], [], [], []
        conv = total = paths = 0
        for p in poses:
            t = time.perf_counter()
            res = refine(name, p)
            per_pose.append(time.perf_counter() - t)
            if len(res.solutions):
                per_sol.append(per_pose[-1] / len(res.solutions))
            per_seed += [r.time_s for r in res]
            per_conv += [r.time_s for r in res if r.success]
            iters += [r.iterations for r in res if r.success]
            conv += sum(r.success for r in res)
            paths += sum(r.solver.startswith("path") for r in res)
            total += len(res)

        def ms(v, pct):
            return float(np.percentile(v, pct) * 1e3)

        out["robots"][name] = {
            "poses": m, "seeds": total, "seed_kind": kind, "converged": conv, "paths": paths,
            "median_ms": ms(per_seed, 50), "p95_ms": ms(per_seed, 95),
            "converged_median_ms": ms(per_conv, 50), "converged_p95_ms": ms(per_conv, 95),
            "median_iterations": float(np.median(iters)),
            "per_pose_median_ms": ms(per_pose, 50), "per_pose_p95_ms": ms(per_pose, 95),
            "per_solution_median_ms": ms(per_sol, 50)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="dq-derive bench")
    p.add_argument("what", nargs="?", default="derivation", choices=BENCHES)
    p.add_argument("--robot", default=None)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json", default=None, help="also write the results as JSON to this file")
    p.add_argument("--plot", default=None, help="chain: write the figure to this file (PNG)")
    args = p.parse_args(argv)
    if args.what in ("kernels", "load"):
        r = (bench_kernels(args.robot or "ur5", repeats=args.repeats) if args.what == "kernels"
             else bench_load(repeats=args.repeats))
        print(report(r) if args.what == "kernels" else load_report(r))
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(r, fh, indent=1)
        return 0
    if args.what == "refine":
        r = bench_refine()
        print(f"derive.refine on {r['machine']}, {r['date']} (time per seed, first call excluded):")
        rows = (("per seed", ""), ("per converged seed", "converged_"), ("per pose", "per_pose_"))
        for name, x in r["robots"].items():
            print(f"  {name} ({x['poses']} poses, {x['seeds']} seeds: {x['seed_kind']}; "
                  f"{x['converged']} converged, {x['paths']} after a continuation path; "
                  f"median {x['median_iterations']:.0f} iterations):")
            for label, key in rows:
                print(f"    {label:<19} median {x[key + 'median_ms']:7.3f} ms   "
                      f"p95 {x[key + 'p95_ms']:7.3f} ms")
            print(f"    {'per solution':<19} median {x['per_solution_median_ms']:7.3f} ms "
                  "(pose time / solutions)")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(r, fh, indent=1)
        return 0
    if args.what == "chain":
        c_rows = bench_chain_c(repeats=args.repeats)
        np_rows = bench_chain_numpy(repeats=max(1, args.repeats // 2))
        print(f"all joint origins of an n-joint DH chain, ns per configuration, on {machine()}")
        print("   n | C: quat reuse  matrix reuse  quat scratch  matrix scratch | numpy: quat reuse  "
              "matrix reuse | mul (quat / matrix, reuse)")
        for c, npr in zip(c_rows, np_rows):
            if c["n"] in (1, 2, 3, 6, 10, 20, 30, 50):
                ops = op_counts(c["n"])
                print(f"  {c['n']:2d} | {c['quat_reuse_ns']:13.1f} {c['matrix_reuse_ns']:13.1f} "
                      f"{c['quat_scratch_ns']:13.1f} {c['matrix_scratch_ns']:15.1f} | "
                      f"{npr['quat_reuse_ns']:17.1f} {npr['matrix_reuse_ns']:13.1f} | "
                      f"{ops['quat_reuse'][0]} / {ops['matrix_reuse'][0]}")
        print(f"max |quaternion - matrix| origin difference: C {max(r['max_diff'] for r in c_rows):.1e}, "
              f"numpy {max(r['max_diff'] for r in np_rows):.1e}")
        if args.plot:
            plot(c_rows, np_rows, args.plot)
            print(f"wrote {args.plot}")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump({"machine": machine(), "c": c_rows, "numpy": np_rows}, fh, indent=1)
        return 0
    if args.what == "fk":
        r = bench_fk(args.robot or "ur5")
        print(f"generated FK kernels of {r['robot']}, batch of {r['n']} poses, on {r['machine']}:")
        for backend in ("c", "numpy", "python"):
            print(f"  {backend:<6} {r[backend]:9.1f} ns per pose (including the call from numpy)")
        return 0
    if args.what == "ik":
        r = bench_ik(args.robot or "ur5")
        print(f"reference IK of {r['robot']} (numpy, all solutions, each checked by FK) on {r['machine']}:")
        print(f"  batch of {r['n']} poses: {r['batch_us']:.1f} us per pose "
              f"({r['mean_solutions']:.2f} solutions per pose on average)")
        print(f"  single calls (reference.ik): {r['single_us']:.0f} us per pose")
        return 0
    r = bench_derivation(args.robot or "ur3", args.repeats)
    print(f"derivation of {r['robot']} (sets B, W, C: derive, simplify, verify, emit), "
          f"{r['repeats']} fresh processes on {r['machine']}:")
    print(f"  derive + verify + emit: median {r['median_derive_verify_emit_s']:.2f} s, "
          f"max {r['max_derive_verify_emit_s']:.2f} s")
    print(f"  import of derive/sympy: median {r['median_import_s']:.2f} s")
    print(f"  whole process:          median {r['median_process_wall_s']:.2f} s, "
          f"max {r['max_process_wall_s']:.2f} s")
    return 0
