"""The numbers of docs/reach.md: the C kernel's IK time per call as the reachability tasks call it,
the per-chunk overhead, and the whole map's wall time on the local scheduler against the kernel
time of the same IK calls divided by the cores.

Run: python benchmarks/bench_reach.py [--robot ur5] [--voxel 0.025] [--orientations 100]
     [--repeats 20] [--json FILE]
"""

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import derive
from derive.apps import reach as R


def kernel_time(robot, repeats: int) -> dict:
    """Seconds per pose of the IK call alone and of the solver's whole count (the call, the
    limit test, the sum) on batches of the tasks' size, the best of ``repeats``."""
    s = R._solver(R._robot_source(robot), robot.id, None, 8)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.8, 0.8, size=(R.BATCH // 100 + 1, 3))
    poses = np.ascontiguousarray(R._poses(pts, R.orientations(100))[:R.BATCH])
    s.count(poses)
    ik, whole, build = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        R._poses(pts, R.orientations(100))
        build.append(time.perf_counter() - t)
        t, clock = time.perf_counter(), [0.0]
        s.count(poses, clock)
        whole.append(time.perf_counter() - t)
        ik.append(clock[0])
    n = len(poses)
    return {"batch": n, "ik_us": min(ik) / n * 1e6, "count_us": min(whole) / n * 1e6,
            "poses_us": min(build) / (len(pts) * 100) * 1e6}


def chunk_overhead(robot, repeats: int) -> dict:
    """Per-chunk overhead: maps of 1 orientation in chunks of 2^3 voxels (almost no IK per task),
    on the synchronous scheduler (the task's own cost: solver lookup, grid, Zarr writes) and the
    threaded one (plus the scheduler's)."""
    out = {}
    for sched in ("synchronous", "threads"):
        best = None
        for _ in range(max(1, repeats // 5)):
            with tempfile.TemporaryDirectory() as tmp:
                m = R.reach(robot, 0.1, 1, Path(tmp) / "o.zarr", chunk=2, scheduler=sched, progress=False)
            st = m.stats
            per = {"chunks": st.computed, "wall_per_chunk_ms": st.wall / st.computed * 1e3,
                   "task_minus_ik_per_chunk_ms": (st.task_seconds - st.ik_seconds) / st.computed * 1e3}
            if best is None or per["wall_per_chunk_ms"] < best["wall_per_chunk_ms"]:
                best = per
        out[sched] = best
    return out


def whole_map(robot, voxel: float, n_or: int, scheduler="threads") -> dict:
    """One map; wall time, and the CPU time of this process (every thread) over the run, which
    the other processes on a shared machine do not inflate."""
    with tempfile.TemporaryDirectory() as tmp:
        t, cpu = time.perf_counter(), time.process_time()
        m = R.reach(robot, voxel, n_or, Path(tmp) / "m.zarr", scheduler=scheduler, progress=False)
        total, cpu = time.perf_counter() - t, time.process_time() - cpu
    st = m.stats
    return {"voxel": voxel, "orientations": n_or, "shape": list(m.reach.shape), "chunks": st.chunks,
            "scheduler": scheduler, "cpu_s": cpu,
            "ik_calls": st.poses, "wall_s": st.wall, "call_s": total, "task_s": st.task_seconds,
            "ik_s": st.ik_seconds, "reachable_voxels": int(np.count_nonzero(np.nan_to_num(m.reach) > 0))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", default="ur5")
    p.add_argument("--voxel", type=float, default=0.025)
    p.add_argument("--orientations", type=int, default=100)
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--json", default=None)
    p.add_argument("--skip-overhead", action="store_true", help="skip the per-chunk overhead runs")
    p.add_argument("--scheduler", default="threads", help="of the whole map")
    a = p.parse_args(argv)
    robot = derive.load_robot(a.robot)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    res = {"robot": robot.name, "cores": cores, "load_before": os.getloadavg()[0]}
    res["kernel"] = kernel_time(robot, a.repeats)
    print(f"IK call {res['kernel']['ik_us']:.3f} us/pose, count (call + limits) {res['kernel']['count_us']:.3f} "
          f"us/pose, poses built {res['kernel']['poses_us']:.3f} us/pose (batch {res['kernel']['batch']}, "
          f"best of {a.repeats})", flush=True)
    res["overhead"] = {} if a.skip_overhead else chunk_overhead(robot, a.repeats)
    for k, v in res["overhead"].items():
        print(f"per-chunk overhead, {k}: {v['wall_per_chunk_ms']:.2f} ms wall per chunk, "
              f"{v['task_minus_ik_per_chunk_ms']:.2f} ms in the task outside the IK ({v['chunks']} chunks)", flush=True)
    res["map"] = whole_map(robot, a.voxel, a.orientations, a.scheduler)
    mp = res["map"]
    kernel = mp["ik_calls"] * res["kernel"]["ik_us"] * 1e-6
    mp["kernel_s"], mp["kernel_per_core_s"] = kernel, kernel / cores
    print(f"map {mp['shape']} x {a.orientations}: {mp['ik_calls']} IK calls in {mp['chunks']} chunks, wall "
          f"{mp['wall_s']:.2f} s ({mp['call_s']:.2f} s with set-up), kernel time {kernel:.2f} s, / {cores} cores "
          f"{kernel / cores:.2f} s: ratio {mp['wall_s'] / (kernel / cores):.2f}; sum of task times "
          f"{mp['task_s']:.2f} s, of IK calls in them {mp['ik_s']:.2f} s; CPU time of the process "
          f"{mp['cpu_s']:.2f} s = {mp['cpu_s'] / kernel:.2f} x the kernel time", flush=True)
    res["load_after"] = os.getloadavg()[0]
    print(f"load average (1 min) before {res['load_before']:.2f}, after {res['load_after']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
