"""Reachability maps and base placement on Dask (issue 34; method and measurements in
docs/reach.md).

:func:`reach` builds a voxel grid over the robot's reach (a bound from its geometry,
:func:`reach_bound`), asks the C IK kernel at every (voxel centre, orientation) whether a
solution exists within the joint limits (any 2 pi winding), and stores the fraction of
orientations that have one in a Zarr group. The orientations are a deterministic
super-Fibonacci spiral on the unit quaternions (:func:`orientations`; M. Alexa, "Super-Fibonacci
Spirals: Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022, Algorithm 1).

:func:`place` scores candidate base placements (x, y, yaw on a grid, at height z) by the
fraction of target poses (world frame) reachable from each.

Both split the work into chunks that are Dask tasks. Each task loads the kernels from the
robot's name or file (checked against its identity ``Robot.id``; cached per worker process),
computes its block and writes it into its own chunk of the Zarr arrays, then marks the chunk
done in the array ``done``: a run that was stopped resumes from the chunks marked done. The
local threaded scheduler is the default (the C kernels are called through ctypes, which
releases the GIL, so the threads run on every core); ``scheduler=ADDRESS`` runs the same tasks
on a dask.distributed cluster, whose workers must see the output folder (the same machine or a
shared file system). A task's result does not depend on where it runs: the same map bit for
bit, on the same machine (the kernels are compiled with -march=native, so an FMA build and a
portable one may differ in the last bit, and a pose exactly at the edge of the reach may then
flip).
"""

from __future__ import annotations

import ctypes
import math
import os
import shutil
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.codegen.loader import kernels
from derive.errors import DeriveError, InputError
from derive.ik.select import LIMIT_SLACK
from derive.model.robot import LIBRARY_DIR, load_robot

TWO_PI = 2.0 * math.pi
#: psi of the super-Fibonacci spiral: the real root of psi^4 = psi + 4 (Alexa 2022, eq. 9)
SUPER_FIBONACCI_PSI = 1.533751168755204288118041
#: Poses per call of the IK kernel inside a task (bounds a task's memory: 48 doubles a pose).
BATCH = 4096
#: A quaternion read from a file or the command line is normalised within this of unit norm.
QUAT_TOL = 1e-4
#: At most this many voxels in a map (a guard against a mistyped --voxel).
MAX_VOXELS = 2 * 10**8
METHOD = "super-Fibonacci spiral (Alexa 2022, Algorithm 1)"


# --------------------------------------------------------------------------- #
# Orientations, the bound, the grid
# --------------------------------------------------------------------------- #
def orientations(n: int) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) spread evenly over SO(3): the super-Fibonacci
    spiral (Alexa 2022, Algorithm 1): with s = i + 1/2, r = sqrt(s/n), R = sqrt(1 - s/n),
    alpha = 2 pi s / sqrt(2), beta = 2 pi s / psi (psi^4 = psi + 4),
    q_i = (r sin alpha, r cos alpha, R sin beta, R cos beta). Deterministic, low discrepancy
    for every n (no sizes preferred, unlike the Hopf-fibration grids)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"orientations: a positive integer, got {n!r}")
    s = np.arange(int(n), dtype=float) + 0.5
    r, big_r = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    alpha, beta = TWO_PI * s / math.sqrt(2.0), TWO_PI * s / SUPER_FIBONACCI_PSI
    return np.stack([r * np.sin(alpha), r * np.cos(alpha), big_r * np.sin(beta), big_r * np.cos(beta)], axis=1)


def _rot(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _path(robot) -> list:
    """The joints from the base to the default end's parent, base first."""
    joints, at = [], robot.ends[robot.default_end].parent
    while at >= 0:
        joints.append(at)
        at = robot.joints[at].parent
    return joints[::-1]


def reach_bound(robot, tool=None) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of a ball, in the base frame (m), that holds every position the end
    frame (the tool frame with ``tool``) can take: by the triangle inequality, the fixed part of
    the chain before the first joint's motion places the centre, the part of the next fixed
    translation along a first revolute joint's axis (invariant under its rotation, e.g. the
    UR's d1) moves it, and every later translation, prismatic travel and the tool's offset add
    their length to the radius. An upper bound, not the exact reach (UR5: 1.103 m from
    (0, 0, d1) against 0.95 m reached)."""
    robot = load_robot(robot)
    lim = robot.limits
    rot, pos = np.eye(3), np.zeros(3)        # the fixed transform so far, in the base frame
    centre, radius, moving = None, 0.0, False
    pending = None                            # (rotation, axis) of the first revolute joint
    items = []
    for j in _path(robot):
        joint = robot.joints[j]
        items += [("op", op) for op in joint.pre] + [("joint", joint)] + [("op", op) for op in joint.post]
    items += [("op", op) for op in robot.ends[robot.default_end].ops]
    for kind, it in items:
        if kind == "joint":
            if not moving:
                centre, moving = pos.copy(), True
                if it.type == "revolute":
                    pending = (rot.copy(), np.asarray(it.axis, dtype=float) / np.linalg.norm(it.axis))
                    continue
            pending = None
            if it.type == "prismatic":
                lo, hi = lim[it.variable] * abs(it.multiplier) + it.mimic_offset
                travel = max(abs(lo), abs(hi)) + abs(float(it.offset))
                if not math.isfinite(travel):
                    raise InputError(f"{robot.name}: joint {it.name!r} is prismatic without limits: "
                                     "its reach has no bound")
                radius += travel
        elif it.kind == "R":
            if not moving:
                rot = rot @ _rot(it.axis, it.angle)
            else:
                pending = None
        else:
            v = np.asarray(it.vector, dtype=float)
            if not moving:
                pos = pos + rot @ v
            elif pending is not None:
                r0, axis = pending
                along = float(v @ axis) * axis
                centre = centre + r0 @ along
                radius += float(np.linalg.norm(v - along))
            else:
                radius += float(np.linalg.norm(v))
    if centre is None:
        centre = pos
    if tool is not None:
        radius += float(np.linalg.norm(dq.to_rt(tool)[1]))
    return centre, radius


def _grid(centre, radius, voxel) -> tuple[np.ndarray, tuple]:
    """(origin (3,), shape): the cube of side >= 2 radius centred on ``centre``, in voxels."""
    n = max(1, int(math.ceil(2.0 * radius / voxel - 1e-9)))
    if n ** 3 > MAX_VOXELS:
        raise InputError(f"voxel: {voxel:g} m gives {n}^3 = {n ** 3:.3g} voxels over a reach of radius "
                         f"{radius:.3f} m (at most {MAX_VOXELS:.0e}); choose a larger voxel")
    return np.asarray(centre, dtype=float) - 0.5 * n * voxel, (n, n, n)


# --------------------------------------------------------------------------- #
# The solver of one worker process
# --------------------------------------------------------------------------- #
def _tool_pose(tool):
    """A tool as a unit dual quaternion (8,), from (x, y, z, qx, qy, qz, qw) or any pose form."""
    if tool is None:
        return None
    arr = None
    if not (isinstance(tool, tuple) and len(tool) == 2):
        try:
            arr = np.asarray(tool, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"tool: expected x, y, z, qx, qy, qz, qw or a pose, got {tool!r}") from None
    if arr is not None and arr.shape == (7,):
        return _xyz_quat_xyzw(arr[None], "tool")[0]
    from derive.kinematics.pose import as_pose
    return as_pose(tool, "tool")


def _xyz_quat_xyzw(rows: np.ndarray, what: str) -> np.ndarray:
    """Unit dual quaternions (n, 8) from rows (x, y, z, qx, qy, qz, qw), each quaternion
    normalised when its norm is within :data:`QUAT_TOL` of 1; InputError naming the row else."""
    rows = np.asarray(rows, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != 7:
        raise InputError(f"{what}: expected rows of 7 numbers x, y, z, qx, qy, qz, qw, got shape {rows.shape}")
    bad = ~np.all(np.isfinite(rows), axis=1)
    if np.any(bad):
        raise InputError(f"{what}: row {int(np.argmax(bad)) + 1} has a NaN or infinite value")
    q = np.concatenate([rows[:, 6:7], rows[:, 3:6]], axis=1)
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0) > QUAT_TOL
    if np.any(off):
        i = int(np.argmax(off))
        raise InputError(f"{what}: row {i + 1}: the quaternion's norm is {norm[i]:.6g}, not 1 (within {QUAT_TOL:g})")
    return dq.from_rt(q / norm[:, None], rows[:, :3])


def _robot_source(robot):
    """What a worker loads the robot from: its library name, else the Robot itself (pickled
    with the task: a URDF's chosen base and tip, a file the workers do not have)."""
    if Path(robot.path).resolve().parent == LIBRARY_DIR.resolve():
        return robot.name
    return robot


def _source_attr(robot) -> str:
    """The robot's library name or its file's path, for the attributes."""
    src = _robot_source(robot)
    return src if isinstance(src, str) else str(Path(robot.path).resolve())


class _Solver:
    """In-limit IK counts of poses of the tool frame, by the C kernels of one robot."""

    def __init__(self, source, rid: str, tool, free_samples: int):
        robot = load_robot(source)
        if robot.id != rid:
            raise DeriveError(f"{source}: the robot loaded here has identity {robot.id}, the map's is {rid} "
                              "(a different file under the same name?)")
        self.robot, self.k = robot, kernels(robot, "c")
        if not self.k.has_ik:
            self.k._require_ik()
        self.tool_inv = None if tool is None else dq.conj_quaternion(np.asarray(tool, dtype=float))
        self.free_samples = free_samples
        self.dof = robot.dof
        if not self.k.free:
            # ctypes releases the GIL during the call: the threads of the local scheduler run in parallel
            lib = ctypes.CDLL(str(self.k.library))
            f = getattr(lib, f"{self.k._manifest['prefix']}_ik_batch")
            f.argtypes = [ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
            f.restype = None
            self._lib, self._ik = lib, f
        lo, hi = robot.limits[:, 0] - LIMIT_SLACK, robot.limits[:, 1] + LIMIT_SLACK
        rev = robot.revolute
        # joints whose limits hold every angle of (-pi, pi] (the kernel's range) need no test
        full = rev & (lo <= -math.pi) & (hi >= math.pi)
        self._check = [(j, lo[j], hi[j], bool(rev[j])) for j in range(self.dof) if not full[j]]

    def in_limits(self, sols: np.ndarray) -> np.ndarray:
        """(m, K) bool: a solution (not NaN padding) with a 2 pi winding of every revolute joint
        inside its limits: exists k with lo <= q + 2 pi k <= hi, i.e.
        floor((hi - q) / 2 pi) >= ceil((lo - q) / 2 pi) (:func:`derive.ik.select.within_limits`
        lists those windings; the same slack)."""
        ok = ~np.isnan(sols[..., 0])
        for j, lo, hi, rev in self._check:
            q = sols[..., j]
            if rev:
                ok &= np.floor((hi - q) / TWO_PI) >= np.ceil((lo - q) / TWO_PI)
            else:
                ok &= (q >= lo) & (q <= hi)
        return ok

    def count(self, poses: np.ndarray, clock: list | None = None) -> np.ndarray:
        """(m,) the number of IK solutions inside the limits of each pose (m, 8) of the tool frame
        in the base frame (a solution counted once, whatever its windings). Seven joints: the
        largest count over ``free_samples`` values of the free parameter over its feasible range
        (:meth:`derive.codegen.loader.Kernels.ik_sweep`, windings counted there). ``clock``: a
        one-element list, the seconds of the IK call are added to it (per task: the threads of a
        worker share the solver)."""
        m = len(poses)
        t = time.perf_counter()
        if self.k.free:
            k = self.k if self.tool_inv is None else self.k.with_tool(dq.conj_quaternion(self.tool_inv))
            sw = k.ik_sweep(poses, self.free_samples, within_limits=True)
            out = np.asarray(sw.counts, dtype=np.int64).reshape(m, -1).max(axis=1)
            self._clock(t, clock)
            return out
        flange = poses if self.tool_inv is None else dq._mul(poses, self.tool_inv[None])
        flange = np.ascontiguousarray(flange, dtype=np.float64)
        sols = np.empty((m, 8, self.dof))
        counts = np.empty(m, dtype=np.intc)
        self._ik(m, flange.ctypes.data, sols.ctypes.data, counts.ctypes.data)
        self._clock(t, clock)
        if not self._check:         # every solution is within the limits (the UR's +-2 pi)
            return counts.astype(np.int64)
        return self.in_limits(sols).sum(axis=1)

    @staticmethod
    def _clock(t0: float, clock: list | None) -> None:
        if clock is not None:
            clock[0] += time.perf_counter() - t0


_SOLVERS: dict = {}


def _solver(source, rid: str, tool: tuple | None, free_samples: int) -> _Solver:
    """The solver of a robot, once per worker process (and per tool), by its identity."""
    key = (rid, tool, free_samples)
    if key not in _SOLVERS:
        _SOLVERS[key] = _Solver(source, rid, tool, free_samples)
    return _SOLVERS[key]


_ARRAYS: dict = {}


def _arrays(path: str, run: str, names: tuple) -> tuple:
    """The Zarr arrays of a map, opened once per worker process and run (``run``: the map's
    ``run_id`` attribute, new whenever a map is created at that path)."""
    import zarr
    key = (path, run, names)
    if key not in _ARRAYS:
        group = zarr.open_group(path, mode="r+")
        if group.attrs.get("run_id") != run:
            raise DeriveError(f"{path}: the map was replaced while its tasks ran")
        _ARRAYS[key] = tuple(group[n] for n in names)
    return _ARRAYS[key]


def _poses(points: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """(len(points) * len(quats), 8) the poses with every position and every rotation (w, x, y, z),
    position-major: [r, 1/2 (0, p) r] (dual = 1/2 t real)."""
    px, py, pz = (0.5 * points[:, i:i + 1] for i in range(3))
    w, x, y, z = (quats[None, :, i] for i in range(4))
    out = np.empty((len(points), len(quats), 8))
    out[..., :4] = quats[None]
    # (0, p) r: scalar -p.v, vector w p + p x v
    out[..., 4] = -(px * x + py * y + pz * z)
    out[..., 5] = w * px + py * z - pz * y
    out[..., 6] = w * py + pz * x - px * z
    out[..., 7] = w * pz + px * y - py * x
    return out.reshape(-1, 8)


# --------------------------------------------------------------------------- #
# Tasks
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class _ReachJob:
    path: str
    run: str
    source: object          # a library name or a Robot
    rid: str
    tool: tuple | None
    n_orientations: int
    origin: tuple
    voxel: float
    shape: tuple
    chunk: int
    centre: tuple
    radius: float
    solutions: bool
    free_samples: int


def _reach_chunk(job: _ReachJob, index: tuple) -> tuple:
    """Compute and write one chunk of a reachability map; returns (index, task seconds, IK
    seconds, poses)."""
    t0 = time.perf_counter()
    solver = _solver(job.source, job.rid, job.tool, job.free_samples)
    clock = [0.0]
    quats = orientations(job.n_orientations)
    lo = [i * job.chunk for i in index]
    hi = [min(s, a + job.chunk) for s, a in zip(job.shape, lo)]
    axes = [np.asarray(job.origin[d]) + (np.arange(lo[d], hi[d]) + 0.5) * job.voxel for d in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    inside = np.linalg.norm(pts - np.asarray(job.centre), axis=1) <= job.radius
    reach_count = np.zeros(len(pts), dtype=np.int64)
    sol_count = np.zeros(len(pts), dtype=np.int64)
    where = np.nonzero(inside)[0]
    step = max(1, BATCH // job.n_orientations)
    poses_done = 0
    for s in range(0, len(where), step):
        at = where[s:s + step]
        c = solver.count(_poses(pts[at], quats), clock).reshape(len(at), job.n_orientations)
        reach_count[at] = (c > 0).sum(axis=1)
        sol_count[at] = c.sum(axis=1)
        poses_done += c.size
    shape = tuple(h - a for a, h in zip(lo, hi))
    region = tuple(slice(a, h) for a, h in zip(lo, hi))
    arrays = _arrays(job.path, job.run, ("reach", "done") + (("solutions",) if job.solutions else ()))
    arrays[0][region] = (reach_count / job.n_orientations).astype(np.float32).reshape(shape)
    if job.solutions:
        arrays[2][region] = sol_count.astype(np.uint32).reshape(shape)
    arrays[1][tuple(slice(i, i + 1) for i in index)] = np.ones((1, 1, 1), dtype=np.uint8)
    return index, time.perf_counter() - t0, clock[0], poses_done


@dataclass(frozen=True)
class _PlaceJob:
    path: str
    run: str
    source: object          # a library name or a Robot
    rid: str
    tool: tuple | None
    targets: tuple          # (T, 8) as nested tuples (pickles small, hashable)
    xs: tuple
    ys: tuple
    z: float
    yaws: tuple
    chunk: int
    free_samples: int


def _base_inverse(x, y, z, yaw) -> np.ndarray:
    """(m, 8) B^-1 for the base poses B = Trans(x, y, z) Rz(yaw) (arrays (m,))."""
    yaw = np.asarray(yaw, dtype=float)
    r = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=-1)
    t = np.stack(np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)), axis=-1)
    return dq.conj_quaternion(dq.from_rt(r, t))


def _place_chunk(job: _PlaceJob, index: tuple) -> tuple:
    """Compute and write one chunk of a placement map: for each candidate base B of the chunk,
    the fraction of targets P whose pose in the base frame, B^-1 P, has an in-limit solution."""
    t0 = time.perf_counter()
    solver = _solver(job.source, job.rid, job.tool, job.free_samples)
    clock = [0.0]
    targets = np.asarray(job.targets, dtype=float)
    i0, j0 = index[0] * job.chunk, index[1] * job.chunk
    i1, j1 = min(len(job.xs), i0 + job.chunk), min(len(job.ys), j0 + job.chunk)
    I, J, K = np.meshgrid(np.arange(i0, i1), np.arange(j0, j1), np.arange(len(job.yaws)), indexing="ij")
    bases = _base_inverse(np.asarray(job.xs)[I.ravel()], np.asarray(job.ys)[J.ravel()], job.z,
                          np.asarray(job.yaws)[K.ravel()])
    frac = np.zeros(len(bases))
    step = max(1, BATCH // len(targets))
    poses_done = 0
    for s in range(0, len(bases), step):
        b = bases[s:s + step]
        poses = dq._mul(np.repeat(b, len(targets), axis=0), np.tile(targets, (len(b), 1)))
        c = solver.count(poses, clock).reshape(len(b), len(targets))
        frac[s:s + len(b)] = (c > 0).sum(axis=1) / len(targets)
        poses_done += c.size
    placement, done = _arrays(job.path, job.run, ("placement", "done"))
    placement[i0:i1, j0:j1, :] = frac.astype(np.float32).reshape(i1 - i0, j1 - j0, len(job.yaws))
    done[index[0]:index[0] + 1, index[1]:index[1] + 1] = np.ones((1, 1), dtype=np.uint8)
    return index, time.perf_counter() - t0, clock[0], poses_done


# --------------------------------------------------------------------------- #
# Running the tasks
# --------------------------------------------------------------------------- #
LOCAL_SCHEDULERS = ("threads", "processes", "synchronous")


class _Bar:
    """A text progress bar on stderr: redrawn in place on a terminal, a line every 10 % else."""

    def __init__(self, label: str, total: int, enabled: bool):
        self.label, self.total, self.done, self.enabled = label, total, 0, enabled and total > 0
        self.t0, self.last, self.tty = time.perf_counter(), -1.0, sys.stderr.isatty()
        self._step = -1
        self.draw()

    def update(self, n: int = 1):
        self.done += n
        self.draw()

    def draw(self):
        if not self.enabled:
            return
        now = time.perf_counter()
        frac = self.done / self.total
        if self.tty:
            if self.done < self.total and now - self.last < 0.2:
                return
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\r{self.label} [{bar:<30}] {self.done}/{self.total} chunks, {now - self.t0:.1f} s")
            if self.done == self.total:
                sys.stderr.write("\n")
        else:
            tenth = int(10 * frac)
            if tenth == self._step:
                return
            self._step = tenth
            sys.stderr.write(f"{self.label}: {self.done}/{self.total} chunks, {now - self.t0:.1f} s\n")
        sys.stderr.flush()
        self.last = now


def _run(func, job, todo: list, scheduler, bar: _Bar) -> list:
    """Run ``func(job, index)`` for every index as Dask tasks on the scheduler; the results."""
    import dask
    token = uuid.uuid4().hex[:12]
    tasks = [dask.delayed(func, pure=False)(job, idx, dask_key_name=f"dq-{func.__name__[1:]}-{token}-"
                                            + "-".join(map(str, idx))) for idx in todo]
    if not tasks:
        return []
    if scheduler is None or scheduler in LOCAL_SCHEDULERS:
        from dask.callbacks import Callback

        class Progress(Callback):
            def _posttask(self, key, result, dsk, state, worker_id):
                bar.update()
        with Progress():
            return list(dask.compute(*tasks, scheduler=scheduler or "threads"))
    try:
        from distributed import Client, as_completed
    except ImportError as exc:                     # pragma: no cover - a declared dependency
        raise DeriveError(f"scheduler {scheduler!r}: dask.distributed is not installed ({exc})") from exc
    try:
        client = Client(scheduler, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"scheduler: cannot connect to the Dask scheduler at {scheduler!r} ({exc})") from None
    try:
        with client.as_current():
            futures = client.compute(tasks)
            for _ in as_completed(futures):
                bar.update()
            return client.gather(futures)
    finally:
        client.close()


def _check_scheduler(scheduler):
    if scheduler is not None and not (isinstance(scheduler, str) and scheduler.strip()):
        raise InputError(f"scheduler: an address such as tcp://host:8786 or one of {LOCAL_SCHEDULERS}, "
                         f"got {scheduler!r}")


def _open(path: Path, params: dict, overwrite: bool, kind: str):
    """The Zarr group at ``path``: created, or opened to resume when its parameters are these."""
    import zarr
    if path.exists():
        if not path.is_dir() or (any(path.iterdir()) and not (path / "zarr.json").is_file()):
            raise InputError(f"out: {path} exists and is not a Zarr group (choose another path)")
        if (path / "zarr.json").is_file():
            try:
                group = zarr.open_group(str(path), mode="r+")
                old = dict(group.attrs.get("params", {}))
            except Exception as exc:   # noqa: BLE001 - any unreadable store is the same input error
                raise InputError(f"out: {path} is not a readable Zarr group ({exc})") from None
            if group.attrs.get("kind") == kind and old == params and not overwrite:
                return group, True
            if not overwrite:
                diff = sorted(k for k in set(old) | set(params) if old.get(k) != params.get(k))
                raise InputError(f"out: {path} holds a {group.attrs.get('kind', 'Zarr group')} with other "
                                 f"parameters ({', '.join(diff) or 'kind'}); pass overwrite (--overwrite) "
                                 "or another path")
            shutil.rmtree(path)
    return zarr.open_group(str(path), mode="w"), False


@dataclass
class Stats:
    """What a run did: chunks computed now and in all, the IK calls, the wall time (s), and the
    summed task and IK-call times (s) of the chunks computed now."""

    chunks: int
    computed: int
    poses: int
    wall: float
    task_seconds: float
    ik_seconds: float


def _stats(results, total, wall) -> Stats:
    return Stats(chunks=total, computed=len(results), poses=int(sum(r[3] for r in results)), wall=wall,
                 task_seconds=float(sum(r[1] for r in results)), ik_seconds=float(sum(r[2] for r in results)))


def _tool_tuple(tool_pose):
    return None if tool_pose is None else tuple(float(v) for v in tool_pose)


def _tool_attr(tool_pose):
    """The tool as (x, y, z, qx, qy, qz, qw) for the attributes, None without one."""
    if tool_pose is None:
        return None
    r, t = dq.to_rt(tool_pose)
    return [float(v) for v in (*t, r[1], r[2], r[3], r[0])]


def _robot_with_ik(robot):
    robot = load_robot(robot)
    k = kernels(robot, "c")
    if not k.has_ik:
        k._require_ik()
    return robot, k


def _positive_int(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"{name}: a positive integer, got {value!r}")
    return int(value)


def _positive(value, name):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: a number > 0, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name}: a finite number > 0, got {value!r}")
    return v


# --------------------------------------------------------------------------- #
# Reachability maps
# --------------------------------------------------------------------------- #
@dataclass
class ReachMap:
    """A reachability map: ``reach`` (nx, ny, nz) the fraction of the orientations with an
    in-limit IK solution at each voxel centre (NaN where a stopped run left a chunk undone);
    ``solutions`` (nx, ny, nz) the in-limit solutions summed over the orientations (None unless
    asked); ``origin`` the corner of voxel 0 (m), ``voxel`` its edge (m): voxel (i, j, k) is
    centred at origin + (i + 1/2, j + 1/2, k + 1/2) voxel. ``path``: the Zarr group (None for
    a map built in memory)."""

    reach: np.ndarray
    solutions: np.ndarray | None
    origin: np.ndarray
    voxel: float
    orientations: int
    centre: np.ndarray
    radius: float
    complete: bool
    path: Path | None
    attrs: dict
    stats: Stats

    def centres(self, index) -> np.ndarray:
        """The voxel centres (..., 3) of integer indices (..., 3)."""
        return self.origin + (np.asarray(index, dtype=float) + 0.5) * self.voxel

    def index(self, points) -> np.ndarray:
        """The voxel indices (..., 3) of points (..., 3) (m); outside the grid they are out of range."""
        return np.floor((np.asarray(points, dtype=float) - self.origin) / self.voxel).astype(np.int64)


def reach(robot, voxel: float, orientations: int = 100, out=None, *, tool=None, scheduler=None,
          chunk: int = 32, solutions: bool = False, free_samples: int = 8, max_chunks: int | None = None,
          overwrite: bool = False, progress: bool = True) -> ReachMap:
    """The reachability map of ``robot`` (a library name, a file, a Robot with a closed-form IK
    kernel) on voxels of edge ``voxel`` (m) over the ball of :func:`reach_bound`, with
    ``orientations`` rotations per voxel centre (:func:`orientations`); written to the Zarr group
    ``out`` (arrays ``reach``, ``solutions`` when asked, ``done``; attributes ``origin``,
    ``voxel``, ``orientations``, ``robot``, ``robot_id``, ``tool`` ...), see docs/reach.md.

    ``tool``: a fixed tool transform (x, y, z, qx, qy, qz, qw) or any pose form; the map is then
    of the tool frame. ``scheduler``: None (the local threaded scheduler), "processes",
    "synchronous", or the address of a dask.distributed scheduler. ``chunk``: voxels per edge of
    a task's block. ``max_chunks``: compute at most this many chunks now (a later call with the
    same parameters resumes). ``free_samples``: seven-joint arms, the values of the free parameter
    tried per pose (the map is then a lower bound: reachable at one of them).
    ``overwrite``: replace a map of other parameters at ``out``."""
    voxel = _positive(voxel, "voxel")
    n_or = _positive_int(orientations, "orientations")
    chunk = _positive_int(chunk, "chunk")
    free_samples = _positive_int(free_samples, "free_samples")
    if max_chunks is not None and (isinstance(max_chunks, bool) or not isinstance(max_chunks, (int, np.integer))
                                   or max_chunks < 0):
        raise InputError(f"max_chunks: an integer >= 0, got {max_chunks!r}")
    _check_scheduler(scheduler)
    robot, k = _robot_with_ik(robot)
    tool_pose = _tool_pose(tool)
    centre, radius = reach_bound(robot, tool_pose)
    origin, shape = _grid(centre, radius, voxel)
    tmp = None
    if out is None:
        tmp = tempfile.mkdtemp(prefix="dq-reach-")
        path = Path(tmp) / "map.zarr"
    else:
        path = Path(out)
    params = {"robot_id": robot.id, "voxel": voxel, "orientations": n_or, "tool": _tool_attr(tool_pose),
              "chunk": chunk, "solutions": bool(solutions), "free_samples": free_samples if k.free else None,
              "method": METHOD}
    try:
        group, resumed = _open(path, params, overwrite, "dq-derive reach map")
        grid = tuple(-(-s // chunk) for s in shape)
        if not resumed:
            group.create_array("reach", shape=shape, chunks=(chunk,) * 3, dtype="float32", fill_value=np.nan)
            if solutions:
                group.create_array("solutions", shape=shape, chunks=(chunk,) * 3, dtype="uint32", fill_value=0)
            group.create_array("done", shape=grid, chunks=(1, 1, 1), dtype="uint8", fill_value=0)
            group.attrs.update({
                "kind": "dq-derive reach map", "params": params, "robot": robot.name, "robot_id": robot.id,
                "robot_source": _source_attr(robot), "dof": robot.dof, "tool": _tool_attr(tool_pose),
                "origin": [float(v) for v in origin], "voxel": voxel, "shape": list(shape),
                "orientations": n_or, "orientation_method": METHOD, "centre": [float(v) for v in centre],
                "radius": radius, "chunk": chunk, "free_parameter": k.free,
                "free_samples": free_samples if k.free else None,
                "reach": "fraction of the orientations with an in-limit IK solution at the voxel centre",
                "dq_derive": __version__, "complete": False, "run_id": uuid.uuid4().hex})
        done = np.asarray(group["done"][...])
        todo = [idx for idx in np.ndindex(grid) if not done[idx]]
        if max_chunks is not None:
            todo = todo[:max_chunks]
        job = _ReachJob(path=str(path.resolve()), run=group.attrs["run_id"], source=_robot_source(robot), rid=robot.id,
                        tool=_tool_tuple(tool_pose), n_orientations=n_or, origin=tuple(map(float, origin)),
                        voxel=voxel, shape=shape, chunk=chunk, centre=tuple(map(float, centre)),
                        radius=radius, solutions=bool(solutions), free_samples=free_samples)
        t0 = time.perf_counter()
        bar = _Bar(f"reach {robot.name}", len(todo), progress)
        results = _run(_reach_chunk, job, todo, scheduler, bar)
        wall = time.perf_counter() - t0
        done = np.asarray(group["done"][...])
        complete = bool(done.all())
        group.attrs["complete"] = complete
        return ReachMap(reach=np.asarray(group["reach"][...]),
                        solutions=np.asarray(group["solutions"][...]) if solutions else None,
                        origin=origin, voxel=voxel, orientations=n_or, centre=centre, radius=radius,
                        complete=complete, path=None if tmp else path, attrs=dict(group.attrs),
                        stats=_stats(results, int(np.prod(grid)), wall))
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)


def open_reach(path) -> ReachMap:
    """A reachability map written by :func:`reach` (complete or not)."""
    import zarr
    path = Path(path)
    try:
        group = zarr.open_group(str(path), mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:   # noqa: BLE001
        raise InputError(f"{path}: not a readable Zarr group ({exc})") from None
    if attrs.get("kind") != "dq-derive reach map":
        raise InputError(f"{path}: not a reachability map of dq-derive")
    sols = np.asarray(group["solutions"][...]) if "solutions" in group else None
    return ReachMap(reach=np.asarray(group["reach"][...]), solutions=sols, origin=np.asarray(attrs["origin"]),
                    voxel=float(attrs["voxel"]), orientations=int(attrs["orientations"]),
                    centre=np.asarray(attrs["centre"]), radius=float(attrs["radius"]),
                    complete=bool(attrs.get("complete")), path=path, attrs=attrs,
                    stats=Stats(int(np.asarray(group["done"][...]).size), 0, 0, 0.0, 0.0, 0.0))


# --------------------------------------------------------------------------- #
# Base placement
# --------------------------------------------------------------------------- #
@dataclass
class Placement:
    """A placement map: ``placement`` (nx, ny, K) the fraction of the targets reachable from the
    base at (xs[i], ys[j], z) turned by yaws[k] about z (NaN where a stopped run left a chunk
    undone); ``best``: the best placements, (x, y, z, yaw, fraction) rows, best first."""

    placement: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    z: float
    yaws: np.ndarray
    targets: np.ndarray
    complete: bool
    path: Path | None
    attrs: dict
    stats: Stats

    def best(self, n: int = 5) -> list:
        """The ``n`` best placements (x, y, z, yaw, fraction), one per position (at its best yaw,
        the first of equal ones): highest fraction first; among equal fractions the position whose
        3 x 3 neighbourhood (every yaw) has the highest mean fraction, the one farthest inside a
        plateau; then grid order (x, then y)."""
        val = np.nan_to_num(np.asarray(self.placement, dtype=float), nan=-1.0)
        per_pos = val.max(axis=2)
        yaw_at = val.argmax(axis=2)
        filled = np.clip(val, 0.0, None).mean(axis=2)
        nx, ny = per_pos.shape
        padded = np.pad(filled, 1, constant_values=np.nan)
        shifted = np.stack([padded[1 + a:1 + a + nx, 1 + b:1 + b + ny] for a in (-1, 0, 1) for b in (-1, 0, 1)])
        neigh = np.nanmean(shifted, axis=0)
        flat = per_pos.ravel()
        order = np.lexsort((np.arange(flat.size), -neigh.ravel(), -flat))[:n]
        rows = []
        for f in order:
            if flat[f] < 0:
                break
            i, j = np.unravel_index(f, per_pos.shape)
            rows.append((float(self.xs[i]), float(self.ys[j]), self.z, float(self.yaws[yaw_at[i, j]]), float(flat[f])))
        return rows


def read_targets(path) -> np.ndarray:
    """Target poses (n, 8) from a CSV file of rows x, y, z, qx, qy, qz, qw (m; a unit quaternion,
    scalar last); a first line that is not numbers is a header; InputError naming the line else."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"targets: cannot read {path} ({getattr(exc, 'strerror', None) or exc})") from None
    rows = []
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    for n, (line_no, line) in enumerate(lines):
        cells = [c.strip() for c in line.split(",")]
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            if n == 0:
                continue                        # a header
            raise InputError(f"targets: {path} line {line_no}: not numbers: {line[:60]!r}") from None
        if len(vals) != 7:
            raise InputError(f"targets: {path} line {line_no}: expected 7 values x,y,z,qx,qy,qz,qw, got {len(vals)}")
        rows.append(vals)
    if not rows:
        raise InputError(f"targets: {path} has no target rows (x,y,z,qx,qy,qz,qw)")
    return _xyz_quat_xyzw(np.asarray(rows), f"targets {path}")


def _axis_values(lo: float, hi: float, step: float, name: str) -> np.ndarray:
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise InputError(f"region: {name} min {lo!r} must be finite and <= max {hi!r}")
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    if n > 100000:
        raise InputError(f"step: {step:g} m gives {n} positions along {name}; choose a larger step")
    return lo + step * np.arange(n)


def place(robot, targets, region, step: float, *, z: float = 0.0, yaw_steps: int = 1, out=None, tool=None,
          scheduler=None, chunk: int = 8, free_samples: int = 8, max_chunks: int | None = None,
          overwrite: bool = False, progress: bool = True) -> Placement:
    """For every candidate base pose B = Trans(x, y, z) Rz(yaw) of the robot, x and y on a grid
    of ``step`` (m) over ``region`` (xmin, xmax, ymin, ymax) and yaw = 2 pi k / ``yaw_steps``,
    the fraction of ``targets`` (poses in the world frame: (n, 8) dual quaternions, (n, 7) rows
    x, y, z, qx, qy, qz, qw, or a CSV file of such rows) whose pose B^-1 P in the base frame has an
    in-limit IK solution. Written to the Zarr group ``out`` (array ``placement`` (nx, ny, K),
    attributes ``xs``, ``ys``, ``z``, ``yaws``...); on Dask like :func:`reach`, whose other
    arguments it shares."""
    step = _positive(step, "step")
    yaw_steps = _positive_int(yaw_steps, "yaw_steps")
    chunk = _positive_int(chunk, "chunk")
    free_samples = _positive_int(free_samples, "free_samples")
    _check_scheduler(scheduler)
    try:
        zf = float(z)
        reg = [float(v) for v in region]
    except (TypeError, ValueError):
        raise InputError(f"region and z: numbers, got {region!r} and {z!r}") from None
    if len(reg) != 4 or not math.isfinite(zf):
        raise InputError(f"region: xmin xmax ymin ymax (4 numbers) and a finite z, got {region!r}, {z!r}")
    if isinstance(targets, (str, os.PathLike)):
        tp = read_targets(targets)
    else:
        arr = np.asarray(targets, dtype=float)
        if arr.ndim == 2 and arr.shape[1] == 7:
            tp = _xyz_quat_xyzw(arr, "targets")
        else:
            from derive.kinematics.pose import as_pose_batch
            tp, _ = as_pose_batch(arr)
    xs = _axis_values(reg[0], reg[1], step, "x")
    ys = _axis_values(reg[2], reg[3], step, "y")
    yaws = TWO_PI * np.arange(yaw_steps) / yaw_steps
    robot, k = _robot_with_ik(robot)
    tool_pose = _tool_pose(tool)
    tmp = None
    if out is None:
        tmp = tempfile.mkdtemp(prefix="dq-place-")
        path = Path(tmp) / "place.zarr"
    else:
        path = Path(out)
    import hashlib
    params = {"robot_id": robot.id, "region": reg, "step": step, "z": zf, "yaw_steps": yaw_steps,
              "tool": _tool_attr(tool_pose), "chunk": chunk,
              "targets_sha256": hashlib.sha256(np.ascontiguousarray(tp).tobytes()).hexdigest(),
              "free_samples": free_samples if k.free else None}
    try:
        group, resumed = _open(path, params, overwrite, "dq-derive placement map")
        shape = (len(xs), len(ys), yaw_steps)
        grid = (-(-len(xs) // chunk), -(-len(ys) // chunk))
        if not resumed:
            group.create_array("placement", shape=shape, chunks=(chunk, chunk, yaw_steps), dtype="float32",
                               fill_value=np.nan)
            group.create_array("targets", shape=tp.shape, chunks=tp.shape, dtype="float64")
            group["targets"][...] = tp
            group.create_array("done", shape=grid, chunks=(1, 1), dtype="uint8", fill_value=0)
            group.attrs.update({
                "kind": "dq-derive placement map", "params": params, "robot": robot.name, "robot_id": robot.id,
                "robot_source": _source_attr(robot), "tool": _tool_attr(tool_pose),
                "xs": [float(v) for v in xs], "ys": [float(v) for v in ys], "z": zf,
                "yaws": [float(v) for v in yaws], "step": step, "targets": len(tp),
                "placement": "fraction of the targets with an in-limit IK solution from the base "
                             "Trans(x, y, z) Rz(yaw)", "dq_derive": __version__, "complete": False,
                "run_id": uuid.uuid4().hex})
        done = np.asarray(group["done"][...])
        todo = [idx for idx in np.ndindex(grid) if not done[idx]]
        if max_chunks is not None:
            todo = todo[:max_chunks]
        job = _PlaceJob(path=str(path.resolve()), run=group.attrs["run_id"], source=_robot_source(robot), rid=robot.id,
                        tool=_tool_tuple(tool_pose), targets=tuple(map(tuple, tp.tolist())),
                        xs=tuple(map(float, xs)), ys=tuple(map(float, ys)), z=zf, yaws=tuple(map(float, yaws)),
                        chunk=chunk, free_samples=free_samples)
        t0 = time.perf_counter()
        bar = _Bar(f"place {robot.name}", len(todo), progress)
        results = _run(_place_chunk, job, todo, scheduler, bar)
        wall = time.perf_counter() - t0
        complete = bool(np.asarray(group["done"][...]).all())
        group.attrs["complete"] = complete
        return Placement(placement=np.asarray(group["placement"][...]), xs=xs, ys=ys, z=zf, yaws=yaws,
                         targets=tp, complete=complete, path=None if tmp else path, attrs=dict(group.attrs),
                         stats=_stats(results, int(np.prod(grid)), wall))
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
