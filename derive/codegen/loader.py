"""``derive.kernels(robot, backend)``: load the generated kernels of a robot.

Backends: "python" (pure Python, one pose at a time), "numpy" (batched), "c" (C99 compiled
on first use with the system compiler into the user's cache folder, loaded with ctypes,
cached by source hash and rebuilt when the source changes). All share one calling
convention: ``.fk(Q) -> (n, 8)`` for joint values ``Q`` of shape (n, dof) (or (dof,) -> (8,)), and
``.ik(P) -> (solutions (n, 8, dof) NaN-padded, counts (n,))`` for unit dual quaternions ``P`` of
shape (n, 8) (or (8,) -> ((8, dof), count)) or 4x4 matrices, for robots with a closed form.

Where the sources come from: the artifacts of the robot's identity (``Robot.id``), first the
``generated/<robot>/`` folder shipped with the package, then the user cache
(:mod:`derive.cache`); only when neither has them are they derived (progress on stderr) and
stored in the user cache. Compiled libraries go to the user cache's ``build/`` folder, named
by a digest of the source, the compiler flags and the CPU.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import os
import platform
import shutil
import subprocess
from pathlib import Path

import numpy as np

from derive.cache import (
    build_folder,
    memo,
    read_manifest,
    shipped_index,
    step,
    store_artifacts,
    task,
    user_folder,
)
from derive.codegen.emit import FILES, kernel_manifest, render_kernels
from derive.errors import DeriveError, InputError, as_finite_array
from derive.kinematics.pose import as_pose_batch
from derive.model.robot import load_robot

BACKENDS = ("python", "numpy", "c")
#: Flags for the C backend. -O3 with -march=native lets the compiler vectorise the batch loops
#: (AVX2/AVX-512 where the CPU has them); -fno-math-errno lets sqrt be an instruction. The
#: results do not depend on them (-std=c99 keeps floating-point contraction off). Override with
#: the environment variable DQ_DERIVE_CFLAGS (for example "-O2" for a portable build).
C_FLAGS = ["-std=c99", "-O3", "-march=native", "-fno-math-errno"]


def c_flags() -> list:
    env = os.environ.get("DQ_DERIVE_CFLAGS")
    return env.split() if env else list(C_FLAGS)


def _machine_key() -> str:
    """What a -march=native build depends on: the architecture and the CPU's feature flags."""
    key = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            key += next((line for line in f if line.startswith(("flags", "Features"))), "")
    except OSError:
        key += platform.processor()
    return key


KERNEL_ROLES = tuple(FILES)


def kernel_folder(robot) -> tuple[Path, dict]:
    """(folder, manifest) of the kernel sources of a robot: the shipped ``generated/<robot>/``
    folder of its identity, else the user cache's, else they are derived now (progress on
    stderr) and stored in the user cache. Never derives when an artifact exists."""
    robot = load_robot(robot)
    for folder in (shipped_index().get(robot.id), user_folder(robot.id)):
        if folder is None:
            continue
        manifest = read_manifest(folder)
        files = manifest.get("files", {})
        if manifest.get("id") == robot.id and all(r in files and (folder / files[r]).is_file()
                                                 for r in KERNEL_ROLES):
            return folder, manifest
    with task(robot.name):
        step(f"no kernels of identity {robot.id} in generated/ or the user cache: deriving them")
        files = render_kernels(robot)
        step("kernel sources rendered")
    folder = store_artifacts(robot.id, files, kernel_manifest(robot))
    return folder, read_manifest(folder)


def _compile(source: Path, prefix: str) -> Path:
    """The shared library of a C kernel source, compiled once per (source, flags, CPU)."""
    text = source.read_text(encoding="utf-8")
    digest = hashlib.sha256((text + " ".join(c_flags()) + _machine_key()).encode()).hexdigest()[:16]
    lib = build_folder() / f"lib{prefix}-{digest}.so"
    if lib.exists():
        return lib
    compiler = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if compiler is None:
        raise DeriveError("backend 'c' needs a C compiler (cc or gcc) on PATH")
    lib.parent.mkdir(parents=True, exist_ok=True)
    tmp = lib.with_name(lib.name + f".{os.getpid()}.tmp")
    res = subprocess.run([compiler, *c_flags(), "-fPIC", "-shared", "-o", str(tmp), str(source), "-lm"],
                         capture_output=True, text=True)
    if res.returncode != 0:
        raise DeriveError(f"compiling the C kernels {source} failed:\n{res.stderr}")
    os.replace(tmp, lib)
    return lib


def _import(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Kernels:
    """The kernels of one robot for one backend."""

    def __init__(self, robot, backend: str):
        self.robot = load_robot(robot)
        self.backend = backend
        self.dof = self.robot.dof
        folder, manifest = kernel_folder(self.robot)
        files = manifest["files"]
        ident = manifest["prefix"]
        self.folder = folder
        if backend == "python":
            self._mod = _import(folder / files["python"], f"{ident}_kinematics_{self.robot.id}")
        elif backend == "numpy":
            self._mod = _import(folder / files["numpy"], f"{ident}_kinematics_numpy_{self.robot.id}")
        elif backend == "c":
            self.library = _compile(folder / files["c_source"], ident)
            self._lib = ctypes.CDLL(str(self.library))
            f = getattr(self._lib, f"{ident}_fk_batch")
            f.argtypes = [ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p]
            f.restype = None
            self._fk_batch = f
            if hasattr(self._lib, f"{ident}_ik_batch"):
                g = getattr(self._lib, f"{ident}_ik_batch")
                g.argtypes = [ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
                g.restype = None
                self._ik_batch = g
        else:
            raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")

    def _q(self, Q):
        q = as_finite_array(Q, "Q", ndim_min=1)
        single = q.ndim == 1
        q2 = q[None, :] if single else q
        if q2.ndim != 2 or q2.shape[1] != self.dof:
            raise InputError(f"Q: expected shape ({self.dof},) or (n, {self.dof}), got {q.shape}")
        return np.ascontiguousarray(q2, dtype=np.float64), single

    def fk(self, Q) -> np.ndarray:
        """Unit dual quaternions (n, 8) of the end frame (sign as the product gives)."""
        q, single = self._q(Q)
        if self.backend == "python":
            out = np.array([self._mod.fk(tuple(row)) for row in q.tolist()], dtype=float).reshape(-1, 8)
        elif self.backend == "numpy":
            out = self._mod.fk(q)
        else:
            out = np.empty((q.shape[0], 8))
            self._fk_batch(q.shape[0], q.ctypes.data, out.ctypes.data)
        return out[0] if single else out

    @property
    def has_ik(self) -> bool:
        if self.backend == "c":
            return hasattr(self, "_ik_batch")
        return hasattr(self._mod, "ik")

    def ik(self, P):
        """All closed-form solutions: (solutions (n, 8, dof) NaN-padded, counts (n,)).

        P: unit dual quaternions (n, 8) / (8,) or matrices (n, 4, 4) / (4, 4) of the end frame;
        a pose farther than 1e-6 from unit raises InputError. At the wrist singularity the free
        joint is chosen for reach (see the generated file's header)."""

        if not self.has_ik:
            why = ("its fixed angles are not all multiples of pi/12, so there are no exact equations "
                   "to solve" if not self.robot.exact else
                   "the extraction found no closed form for this chain")
            raise DeriveError(f"{self.robot.name}: no closed-form IK kernel ({why}); "
                              "use derive.refine")
        poses, single = as_pose_batch(P)
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        n = poses.shape[0]
        if self.backend == "python":
            sols = np.full((n, 8, self.dof), np.nan)
            counts = np.zeros(n, dtype=np.int64)
            for i, row in enumerate(poses.tolist()):
                found = self._mod.ik(row)
                counts[i] = len(found)
                if found:
                    sols[i, :len(found)] = found
        elif self.backend == "numpy":
            sols, counts = self._mod.ik(poses)
        else:
            sols = np.empty((n, 8, self.dof))
            c = np.empty(n, dtype=np.intc)
            self._ik_batch(n, poses.ctypes.data, sols.ctypes.data, c.ctypes.data)
            counts = c.astype(np.int64)
        return (sols[0], int(counts[0])) if single else (sols, counts)


def kernels(robot, backend: str = "numpy") -> Kernels:
    """The generated kernels of ``robot`` (a library name, a description file under any name,
    or a :class:`~derive.model.robot.Robot`) for ``backend`` ("python", "numpy", "c"), loaded
    from the artifacts of its identity (see :func:`kernel_folder`); once per process."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    r = load_robot(robot)
    key = (r.id, backend, tuple(c_flags()) if backend == "c" else ())
    return memo("kernels", key, lambda: Kernels(r, backend))
