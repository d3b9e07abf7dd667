"""Start-up and first-call latency (``dq-derive bench load``).

Every measurement runs in a fresh Python process (``sys.executable -c ...``) whose
``DQ_DERIVE_CACHE`` points at a temporary folder made for it, so the numbers do not depend on
the user's cache:

* ``import derive``;
* warm cache: ``derive.kernels("ur5", "c")`` beyond the import, with the compiled library
  already in the cache (a first process warms it), and the latency of one ``k.fk(q)`` and one
  ``k.ik(pose)`` call from Python after loading (the first call and the median of later ones);
* warm cache: the first ``derive.refine("ur5", pose)`` in the process;
* cold cache (an empty folder per run): ``derive.kernels("ur5", "c")``, mostly the C compile;
* empty cache: ``derive.kernels(path, "numpy")`` of a UR5 file whose alphas are decimal radians
  that are not multiples of pi (FK derived from the numeric product, no closed-form IK), of
  the UR5 with ``alpha: 1.5707963267948966`` (snaps to pi/2: the UR5's identity), and of the
  library's ``general-6r``. The number of stderr lines shows the progress output.

A derivation can take tens of seconds, so each measurement stops repeating once its runs have
taken ``budget_s`` (it always runs once); the report gives the number of runs. Not a test: the
numbers go to docs/benchmarks.md.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from derive.bench.machine import machine

#: The fresh process: argv = mode, robot, backend. The result is the last stdout line, as JSON.
_LOAD_RUN = r"""
import json, sys, time
t0 = time.perf_counter()
import derive
t1 = time.perf_counter()
mode, robot, backend = sys.argv[1:4]
out = {"import_s": t1 - t0}
if mode == "kernels":
    k = derive.kernels(robot, backend)
    out["load_s"] = time.perf_counter() - t1
    out["has_ik"] = bool(k.has_ik)
    out["id"] = k.robot.id
    out["folder"] = str(k.folder)
    if sys.argv[4:] == ["calls"]:
        import numpy as np
        q = np.array([0.3, -1.2, 1.4, -0.5, 1.1, 0.7])
        pose = derive.reference.fk(k.robot, q)
        def lat(f, x, n=2000):
            t = time.perf_counter(); f(x); first = time.perf_counter() - t
            ts = []
            for _ in range(n):
                t = time.perf_counter(); f(x); ts.append(time.perf_counter() - t)
            ts.sort()
            return first, ts[len(ts) // 2]
        out["fk_first_s"], out["fk_call_s"] = lat(k.fk, q)
        if k.has_ik:
            out["ik_first_s"], out["ik_call_s"] = lat(k.ik, pose)
            out["ik_count"] = int(k.ik(pose)[1])
elif mode == "refine":
    import numpy as np
    pose = derive.reference.fk(robot, np.array([0.3, -1.2, 1.4, -0.5, 1.1, 0.7]))
    t = time.perf_counter()
    res = derive.refine(robot, pose)
    out["refine_s"] = time.perf_counter() - t
    out["solutions"] = int(len(res.solutions))
    out["seeds"] = len(res)
    out["converged"] = int(sum(r.success for r in res))
print("BENCH-LOAD " + json.dumps(out))
"""

#: A UR5 file; {name} and {alpha} are filled in (alpha: the value written for pi/2).
_UR5_FILE = """\
# UR5 with its alphas written as decimal numbers (dq-derive bench load).
name: {name}
convention: standard_dh
units: {{length: m, angle: rad}}
parameters: {{d1: 0.089159, a2: -0.425, a3: -0.39225, d4: 0.10915, d5: 0.09465, d6: 0.0823}}
joints:
  - {{name: shoulder_pan,  d: d1, a: 0,  alpha: {alpha},  limits: [-2*pi, 2*pi]}}
  - {{name: shoulder_lift, d: 0,  a: a2, alpha: 0,     limits: [-2*pi, 2*pi]}}
  - {{name: elbow,         d: 0,  a: a3, alpha: 0,     limits: [-2*pi, 2*pi]}}
  - {{name: wrist_1,       d: d4, a: 0,  alpha: {alpha},  limits: [-2*pi, 2*pi]}}
  - {{name: wrist_2,       d: d5, a: 0,  alpha: -{alpha}, limits: [-2*pi, 2*pi]}}
  - {{name: wrist_3,       d: d6, a: 0,  alpha: 0,     limits: [-2*pi, 2*pi]}}
"""

#: One fresh process may take this long before it counts as hung (s).
TIMEOUT_S = 300.0


def cpu_flags() -> dict:
    """Whether the CPU has AVX2 / AVX-512F (from /proc/cpuinfo; None when unknown)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            line = next((ln for ln in fh if ln.startswith("flags")), None)
    except OSError:
        line = None
    if line is None:
        return {"avx2": None, "avx512f": None}
    flags = set(line.split(":", 1)[1].split())
    return {"avx2": "avx2" in flags, "avx512f": "avx512f" in flags}


def _run(mode: str, robot: str, backend: str, cache: str, *extra: str) -> dict:
    """One fresh process; its result, wall time and stderr line count (or the error)."""
    env = {**os.environ, "DQ_DERIVE_CACHE": cache}
    cmd = [sys.executable, "-c", _LOAD_RUN, mode, robot, backend, *extra]
    t = time.perf_counter()
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=TIMEOUT_S,
                             check=False)
    except subprocess.TimeoutExpired as e:
        err = e.stderr.decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
        return {"error": f"no result after {TIMEOUT_S:g} s (hung?)", "stderr": err}
    wall = time.perf_counter() - t
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("BENCH-LOAD ")]
    if res.returncode != 0 or not lines:
        return {"error": f"exit status {res.returncode}", "stderr": res.stderr}
    r = json.loads(lines[-1][len("BENCH-LOAD "):])
    r["process_wall_s"] = wall
    r["stderr_lines"] = len(res.stderr.splitlines())
    r["stderr"] = res.stderr
    return r


def _series(label: str, runs_of, repeats: int, budget_s: float) -> dict:
    """Up to ``repeats`` runs of ``runs_of()`` (at least one; fewer once ``budget_s`` is spent);
    median and min of every number, the last run's other fields."""
    runs, t0 = [], time.perf_counter()
    for _ in range(repeats):
        r = runs_of()
        if "error" in r:
            return {"label": label, "runs": len(runs), "error": r["error"], "stderr": r["stderr"]}
        runs.append(r)
        if time.perf_counter() - t0 > budget_s:
            break
    out = {"label": label, "runs": len(runs)}
    last = runs[-1]
    for k, v in last.items():
        if isinstance(v, float):
            vals = [r[k] for r in runs]
            out[f"median_{k}"] = statistics.median(vals)
            out[f"min_{k}"] = min(vals)
        elif k == "stderr":
            out["stderr_last"] = v
        else:
            out[k] = v
    out["stderr_lines"] = [r["stderr_lines"] for r in runs]
    return out


def bench_load(repeats: int = 5, budget_s: float = 40.0) -> dict:
    """All load measurements (see the module docstring)."""
    out = {"machine": machine(), "date": time.strftime("%Y-%m-%d"), "cpu": cpu_flags(),
           "python": sys.executable, "repeats": repeats, "budget_s": budget_s, "results": {}}
    res = out["results"]
    with tempfile.TemporaryDirectory(prefix="dq-bench-load-") as tmp:
        tmp = Path(tmp)
        warm = str(tmp / "warm")

        def fresh() -> str:
            return tempfile.mkdtemp(dir=tmp, prefix="cold-")

        res["import"] = _series("import derive", lambda: _run("import", "-", "-", warm), repeats, budget_s)
        # warm the cache folder: the C library of ur5 (and anything refine stores)
        _run("kernels", "ur5", "c", warm)
        _run("refine", "ur5", "-", warm)
        res["warm_c"] = _series('warm cache: kernels("ur5", "c")',
                                lambda: _run("kernels", "ur5", "c", warm, "calls"), repeats, budget_s)
        res["warm_refine"] = _series('warm cache: first refine("ur5", pose)',
                                     lambda: _run("refine", "ur5", "-", warm), repeats, budget_s)
        res["cold_c"] = _series('cold cache: kernels("ur5", "c")',
                                lambda: _run("kernels", "ur5", "c", fresh()), repeats, budget_s)
        decimal = tmp / "ur5-decimal.yaml"
        decimal.write_text(_UR5_FILE.format(name="ur5-decimal", alpha="1.5708"), encoding="utf-8")
        snapped = tmp / "ur5-float-pi2.yaml"
        snapped.write_text(_UR5_FILE.format(name="ur5-float-pi2", alpha="1.5707963267948966"),
                           encoding="utf-8")
        out["files"] = {"decimal": decimal.read_text(encoding="utf-8"),
                        "snapped": snapped.read_text(encoding="utf-8")}
        for key, robot, label in (
                ("decimal_numpy", str(decimal), 'empty cache: kernels(ur5-decimal.yaml [alpha 1.5708], "numpy")'),
                ("snapped_numpy", str(snapped),
                 'empty cache: kernels(ur5-float-pi2.yaml [alpha 1.5707963267948966], "numpy")'),
                ("general6r_numpy", "general-6r", 'empty cache: kernels("general-6r", "numpy")')):
            res[key] = _series(label, lambda r=robot: _run("kernels", r, "numpy", fresh()), repeats, budget_s)
    return out


TARGETS = (("warm_c", "median_load_s", 0.2, "warm kernels(\"ur5\", \"c\") beyond import"),
           ("warm_refine", "median_refine_s", 1.0, "first refine"),
           ("decimal_numpy", "median_load_s", 60.0, "decimal 6R derived"))


def report(r: dict) -> str:
    cpu = r["cpu"]
    head = (f"load and first-call times, fresh process each, on {r['machine']}, {r['date']} "
            f"(avx2 {cpu['avx2']}, avx512f {cpu['avx512f']}); up to {r['repeats']} runs "
            f"(fewer once a measurement has taken {r['budget_s']:g} s); median / min:")
    lines = [head]

    def t(x, key, unit="s"):
        scale = {"s": 1, "ms": 1e3, "us": 1e6}[unit]
        return f"{x['median_' + key] * scale:8.3f} / {x['min_' + key] * scale:8.3f} {unit}"

    for key, x in r["results"].items():
        lines.append(f"  {x['label']}  [{x['runs']} runs]")
        if "error" in x:
            lines.append(f"    FAILED: {x['error']}")
            lines += ["    | " + ln for ln in x["stderr"].rstrip().splitlines()]
            continue
        lines.append(f"    import derive            {t(x, 'import_s')}")
        if key != "import":
            if "median_load_s" in x:
                lines.append(f"    kernels() beyond import  {t(x, 'load_s')}   "
                             f"(closed-form IK: {x['has_ik']}; id {x['id']}; from {x['folder']})")
            if "median_fk_first_s" in x:
                lines.append(f"    k.fk(q)   first call     {t(x, 'fk_first_s', 'us')}; "
                             f"later calls {t(x, 'fk_call_s', 'us')}")
            if "median_ik_first_s" in x:
                lines.append(f"    k.ik(pose) first call    {t(x, 'ik_first_s', 'us')}; "
                             f"later calls {t(x, 'ik_call_s', 'us')} ({x['ik_count']} solutions)")
            if "median_refine_s" in x:
                lines.append(f"    refine() first call      {t(x, 'refine_s')}   "
                             f"({x['solutions']} solutions, {x['converged']} of {x['seeds']} seeds converged)")
        lines.append(f"    whole process            {t(x, 'process_wall_s')}")
        lines.append(f"    stderr lines per run     {x['stderr_lines']}")
        for ln in x.get("stderr_last", "").rstrip().splitlines()[:6]:
            lines.append(f"    | {ln}")
    lines.append("targets:")
    for key, field, limit, name in TARGETS:
        x = r["results"].get(key, {})
        if field in x:
            ok = x[field] < limit
            extra = ""
            if key == "decimal_numpy":
                ok = ok and min(x["stderr_lines"]) > 0
                extra = f", progress lines {x['stderr_lines']}"
            lines.append(f"  {name}: {x[field]:.3f} s (target < {limit:g} s{extra}): "
                         f"{'met' if ok else 'MISSED'}")
        else:
            lines.append(f"  {name}: no measurement ({x.get('error', 'missing')})")
    return "\n".join(lines)
