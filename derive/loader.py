"""``derive.kernels(robot, backend)``: load the generated kernels of a robot.

Backends: "python" (pure Python, one pose at a time), "numpy" (batched), "c" (C99 compiled
on first use with the system compiler into the user's cache folder, loaded with ctypes,
cached by source hash and rebuilt when the source changes). All share one calling
convention: ``.fk(Q) -> (n, 8)`` for joint values ``Q`` of shape (n, dof) (or (dof,) -> (8,)), and
``.ik(P) -> (solutions (n, 8, dof) NaN-padded, counts (n,))`` for unit dual quaternions ``P`` of
shape (n, 8) (or (8,) -> ((8, dof), count)) or 4x4 matrices, for robots with a closed form.

Cache folder: ``$DQ_DERIVE_CACHE``, else ``$XDG_CACHE_HOME/dq-derive``, else ``~/.cache/dq-derive``.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from .emit import identifier, render_kernels
from .errors import DeriveError, InputError, as_finite_array
from .robot import load_robot

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
    import platform
    key = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            key += next((line for line in f if line.startswith(("flags", "Features"))), "")
    except OSError:
        key += platform.processor()
    return key


def cache_dir() -> Path:
    base = os.environ.get("DQ_DERIVE_CACHE")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "dq-derive"


def _sources(robot_name: str) -> tuple[Path, dict]:
    files = render_kernels(robot_name)
    text = "".join(files[k] for k in sorted(files)) + " ".join(c_flags()) + _machine_key()
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    folder = cache_dir() / f"{identifier(robot_name)}-{digest}"
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        path = folder / name
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
    return folder, files


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
        folder, _ = _sources(self.robot.name)
        ident = identifier(self.robot.name)
        self.folder = folder
        if backend == "python":
            self._mod = _import(folder / f"{ident}_kinematics.py", f"{ident}_kinematics")
        elif backend == "numpy":
            self._mod = _import(folder / f"{ident}_kinematics_numpy.py", f"{ident}_kinematics_numpy")
        elif backend == "c":
            lib = folder / f"lib{ident}_kinematics.so"
            if not lib.exists():
                compiler = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
                if compiler is None:
                    raise DeriveError("backend 'c' needs a C compiler (cc or gcc) on PATH")
                res = subprocess.run([compiler, *c_flags(), "-fPIC", "-shared", "-o", str(lib) + ".tmp",
                                      str(folder / f"{ident}_kinematics.c"), "-lm"],
                                     capture_output=True, text=True)
                if res.returncode != 0:
                    raise DeriveError(f"compiling the C kernels failed:\n{res.stderr}")
                os.replace(str(lib) + ".tmp", lib)
            self._lib = ctypes.CDLL(str(lib))
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
        from .ik import as_pose_batch

        if not self.has_ik:
            raise DeriveError(f"{self.robot.name}: no closed-form IK kernel (the extraction found "
                              "no program for this chain); use derive.refine")
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


_LOADED: dict = {}


def kernels(robot, backend: str = "numpy") -> Kernels:
    """The generated kernels of ``robot`` for ``backend`` ("python", "numpy", "c")."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    r = load_robot(robot)
    key = (r.name, r.path, backend)
    if key not in _LOADED:
        _LOADED[key] = Kernels(r, backend)
    return _LOADED[key]
