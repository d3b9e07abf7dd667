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
by a digest of the source, the compiler (path and version), its flags and the CPU (and, for the
CPython extension, the template's rendered text, Python's and numpy's versions).

Integrity (docs/reliability.md, "Cache"): each file of the user cache is verified against the
SHA-256 its manifest records before it is imported or ``dlopen``ed; one that fails the check, or
fails to load, is made again (derived, or compiled) with one line on stderr saying why, and a
second failure is a DeriveError. One process derives or compiles an entry while the others wait
(:func:`derive.cache.build_lock`).
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import functools
import hashlib
import importlib.machinery
import importlib.util
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.algebra.dualquat import UNIT_TOL
from derive.cache import (
    build_folder,
    build_folders,
    build_lock,
    fallback_root,
    locked,
    memo,
    notice,
    read_manifest,
    record,
    shipped_index,
    step,
    store_artifacts,
    task,
    user_folder,
    user_folders,
    verify,
    writable_root,
)
# the package, not derive.codegen.emit / .templates: the emitters (sympy, jinja2) are imported on
# first use through its attributes (derive/codegen/__init__.py), only when kernels are derived
# or an extension is built, so loading shipped or cached kernels does not import them
import derive.codegen as codegen
from derive.codegen.formats import FILES, KERNEL_FORMAT, nominal_key, template_source
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik import select
from derive.ik import redundant
from derive.ik.closed_form import ik_batch as reference_ik_batch
from derive.ik.redundant import free_choice, missing_free_message
from derive.kinematics.pose import as_pose, as_pose_batch
from derive.model.robot import load_robot

BACKENDS = ("python", "numpy", "c")
#: Flags for the C backend. -O3 with -march=native lets the compiler vectorise the batch loops
#: (AVX2/AVX-512 where the CPU has them); -fno-math-errno lets sqrt be an instruction. The
#: results do not depend on them (-std=c99 keeps floating-point contraction off). Override with
#: the environment variable DQ_DERIVE_CFLAGS (for example "-O2" for a portable build).
C_FLAGS = ["-std=c99", "-O3", "-march=native", "-fno-math-errno"]

#: Added on x86: gcc's tuning for AMD Zen 1 (-march=native there is znver1) vectorises with
#: 16-byte vectors even where AVX2 gives 32; with 32 the UR5 batch IK runs 1590 -> 890
#: instructions per pose and about 20 % faster on Zen 1 (docs/benchmarks.md). Other AVX2 and
#: AVX-512 targets prefer 32-byte vectors already; without AVX the flag changes nothing.
X86_FLAGS = ["-mprefer-vector-width=256"]

#: Added for gcc: no second, narrower vector version of each loop for its remainder. The batch
#: loops run over blocks of 64 poses (no remainder but the last block's few poses), and the
#: second version cost a third of the compile time (UR5: 13.8 -> 8.7 s at -O3).
GCC_FLAGS = ["--param=vect-epilogues-nomask=0"]


def c_compiler() -> str | None:
    """The C compiler of the C backend: $CC (default cc), else gcc; None when there is none."""
    return shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")


@functools.lru_cache(maxsize=None)
def _is_gcc(compiler: str) -> bool:
    try:
        out = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return False
    return "Free Software Foundation" in out and "clang" not in out.lower()


@functools.lru_cache(maxsize=None)
def _compiler_version(compiler: str) -> str:
    try:
        return subprocess.run([compiler, "--version"], capture_output=True, text=True,
                              timeout=60).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _compiler_key() -> str:
    """What a build depends on besides its source and flags: the compiler's path and version."""
    cc = c_compiler()
    return "" if cc is None else f"{cc}\0{_compiler_version(cc)}"


def c_flags() -> list:
    """The compiler flags of the C backend: DQ_DERIVE_CFLAGS when set, else :data:`C_FLAGS`,
    with :data:`X86_FLAGS` on x86 and :data:`GCC_FLAGS` when :func:`c_compiler` is gcc."""
    env = os.environ.get("DQ_DERIVE_CFLAGS")
    if env:
        return env.split()
    x86 = platform.machine().lower() in ("x86_64", "amd64", "i386", "i686")
    cc = c_compiler()
    return (list(C_FLAGS) + (list(X86_FLAGS) if x86 else [])
            + (list(GCC_FLAGS) if cc is not None and _is_gcc(cc) else []))


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


def kernel_folder(robot, free: str | None = None, rebuild: str | None = None,
                  nominal=None) -> tuple[Path, dict]:
    """(folder, manifest) of the kernel sources of a robot: the shipped ``generated/<robot>/``
    folder of its identity, else the user cache's (its files verified against the manifest's
    checksums; one that fails is reported on stderr and derived again), else they are derived
    now (progress on stderr) and stored in the user cache; while one process derives them, the
    others wait for it (:func:`derive.cache.build_lock`) and load its result. Never derives
    when an artifact of the current calling convention
    (:data:`~derive.codegen.emit.KERNEL_FORMAT`) exists.
    ``free``: the kernels of a 7-joint arm's alternative free parameter ("q3" for the SRS
    class, :func:`derive.ik.redundant.free_choice`), kept in the user cache beside the default ones, in a folder and
    under a manifest ``id`` of "<identity>-<free>"; their functions are named <robot>_<free>_*.
    ``rebuild``: why the kernels found before did not load; they are derived again whatever the
    folders hold. ``nominal``: a near-class arm's :class:`derive.ik.nearclass.Nominal`; the
    kernels that solve its closed form and polish (:mod:`derive.codegen.polish`) are kept in the
    user cache under "<identity>-n<key>", the key naming the nominal robot and the relation
    (:func:`derive.codegen.formats.nominal_key`)."""
    robot = load_robot(robot)
    free = free_choice(robot if nominal is None else nominal.robot, free)
    # the identity leaves the joint limits out; the kernels compile them in, so their key has
    # the limits' part too: a limit edit renders and compiles again, it derives nothing
    key = (robot.id if free is None else f"{robot.id}-{free}") + f"-L{robot.limits_id}"
    if nominal is not None:
        key = f"{key}-n{nominal_key(nominal)}"
    if rebuild is None:
        shipped = shipped_index().get(key) if free is None and nominal is None else None
        found = _find_kernels(key, free, shipped, report=True)
        if found is not None:
            return found
    with contextlib.ExitStack() as stack:
        try:
            stack.enter_context(build_lock(user_folder(key, writable_root()),
                                           f"the kernels of {robot.name} ({key})"))
        except OSError as exc:             # the lock's folder could not be made: derive unlocked
            fallback_root(exc)
        else:
            if rebuild is None:
                found = _find_kernels(key, free, None, report=False)
                if found is not None:      # another process derived them while this one waited
                    return found
        files = _derive_kernels(robot, key, free, rebuild, nominal)
        folder = store_artifacts(key, files, codegen.emit.kernel_manifest(robot, free, nominal))
    return folder, read_manifest(folder)


def _find_kernels(key: str, free, shipped, report: bool):
    """(folder, manifest) of complete kernels of ``key``: the shipped folder, then the user
    cache's folders with their checksums verified (a failure said on stderr when ``report``)."""
    for folder in [shipped, *user_folders(key)]:
        if folder is None:
            continue
        manifest = read_manifest(folder)
        files = manifest.get("files", {})
        # a user folder records the whole key as its id, a shipped one the identity and limits
        shipped_key = f"{manifest.get('id')}-L{manifest.get('limits')}" if folder == shipped else None
        if not (key in (manifest.get("id"), shipped_key) and manifest.get("format") == KERNEL_FORMAT
                and all(r in files for r in KERNEL_ROLES) and (free is None or manifest.get("free") == free)):
            continue
        if folder != shipped:
            why = verify(folder, [files[r] for r in KERNEL_ROLES])
            if why:
                if report:
                    notice(f"{why}: deriving the kernels of {key} again")
                continue
        elif not all((folder / files[r]).is_file() for r in KERNEL_ROLES):
            continue
        return folder, manifest
    return None


def _derive_kernels(robot, key: str, free, rebuild: str | None, nominal=None) -> dict:
    if rebuild:
        notice(f"{rebuild}: deriving the kernels of {key} again")
    with task(robot.name):
        step(f"deriving the kernels of {key} again" if rebuild else
             f"no kernels of identity {key} in generated/ or the user cache: deriving them")
        files = codegen.emit.render_kernels(robot, free=free, nominal=nominal)
        step("kernel sources rendered")
    return files


def _verified_build(name: str) -> Path | None:
    """The compiled file ``name`` from a build folder where it matches its recorded checksum;
    None when there is none (a file that fails the check is said on stderr)."""
    for folder in build_folders():
        lib = folder / name
        if not lib.exists():
            continue
        why = verify(folder, [name])
        if why is None:
            return lib
        notice(f"{why}: compiling it again")
    return None


def _build(name: str, what: str, lock_on: Path, make) -> Path | None:
    """The compiled file ``name`` of a build folder, verified (:func:`_verified_build`), else
    made by ``make(tmp)`` (a compiler writing ``tmp``; False when it failed, and then None)
    into the writable build folder, renamed into place and recorded with its checksum.
    Compilers of the same file wait for each other (a lock on ``lock_on``)."""
    lib = _verified_build(name)
    if lib is not None:
        return lib
    for attempt in range(2):
        folder = build_folder(writable_root())
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with locked(lock_on):          # a process that needs the same file meanwhile waits
                lib = _verified_build(name)
                if lib is not None:
                    return lib
                lib = folder / name
                tmp = lib.with_name(lib.name + f".{os.getpid()}.tmp")
                if not make(tmp):
                    return None
                os.replace(tmp, lib)
                record(folder, [name])
                return lib
        except OSError as exc:
            if attempt:
                raise DeriveError(f"{what}: cannot be written even to the temporary cache ({exc})") from None
            fallback_root(exc)
    return None


def _compile(source: Path, prefix: str, again: str | None = None) -> Path:
    """The shared library of a C kernel source, compiled once per (source, compiler, flags,
    CPU), verified against its checksum before use. ``again``: why the library found before
    did not load; it is compiled anew (removed first)."""
    text = source.read_text(encoding="utf-8")
    digest = hashlib.sha256((text + " ".join(c_flags()) + _machine_key() + _compiler_key())
                            .encode()).hexdigest()[:16]
    name = f"lib{prefix}-{digest}.so"
    if again:
        _discard(name, again)
    compiler = c_compiler()

    def make(tmp):
        if compiler is None:
            raise DeriveError("backend 'c' needs a C compiler (cc or gcc) on PATH")
        res = subprocess.run([compiler, *c_flags(), "-fPIC", "-shared", "-o", str(tmp), str(source), "-lm"],
                             capture_output=True, text=True)
        if res.returncode != 0:
            raise DeriveError(f"compiling the C kernels {source} failed:\n{res.stderr}")
        return True
    return _build(name, f"the C library of {source}", source, make)


def _discard(name: str, why: str) -> None:
    """Say why a compiled file is made again, and remove it from the build folders it is in."""
    notice(f"{why}: compiling {name} again")
    for folder in build_folders():
        try:
            (folder / name).unlink()
        except OSError:
            pass


#: |q| beyond this is refused by the C backend: dq_sincos reduces its argument accurately up to
#: about this size (a revolute joint's value can always be reduced modulo 2 pi first).
Q_MAX = 1e6


def _extension(robot, source: Path, prefix: str, has_ik: bool, free: str | None = None, max_solutions: int = 8):
    # prefix: the kernels' identifier stem from the manifest (emit.identifier, not called here:
    # the load path does no code generation)
    """The CPython extension module of a C kernel source (templates/pyext.c.j2: input checks in
    C, single calls as batches of one), compiled once per (source, template, compiler, flags,
    CPU, Python, numpy) and verified against its checksum before it is imported; one that does
    not import is compiled again once (said on stderr). None when it cannot be built (no
    Python headers, no compiler, a compiler error, said on stderr), and the loader uses ctypes
    instead."""
    include = sysconfig.get_paths().get("include")
    if not include or not (Path(include) / "Python.h").exists():
        return None
    context = dict(
        version=__version__, robot=robot.name, kernel_name=source.name, kernel_path=str(source),
        prefix=prefix, dof=robot.dof, max_solutions=max_solutions, has_ik=has_ik, free=free, q_max=repr(Q_MAX),
        revolute=robot.revolute.tolist(),
        unit_tol=repr(UNIT_TOL), module="MODULE")
    ext_suffix = sysconfig.get_config_var("EXT_SUFFIX")
    # keyed by the template and its context (the rendered text is a function of both), so that a
    # built extension loads without jinja2; rendered only to build
    digest = hashlib.sha256((template_source("pyext.c.j2") + json.dumps(context, sort_keys=True)
                             + source.read_text(encoding="utf-8") + " ".join(c_flags())
                             + _machine_key() + _compiler_key() + ext_suffix + sys.version
                             + np.__version__ + np.get_include())
                            .encode()).hexdigest()[:16]
    module = f"_dqk_{prefix}_{digest}"
    name = f"{module}{ext_suffix}"
    compiler = c_compiler()

    def make(tmp):
        if compiler is None:
            return False
        # this process's own source and output names, renamed into place when built: another
        # process never sees a partial file
        src = (tmp.parent / name).with_suffix(".c")
        src_tmp = src.with_name(f"{src.stem}.{os.getpid()}.tmp.c")
        text = codegen.templates.template_environment().get_template("pyext.c.j2").render(
            context).replace("MODULE", module)
        src_tmp.write_text(text, encoding="utf-8")
        res = subprocess.run([compiler, *c_flags(), "-fPIC", "-shared", f"-I{include}",
                              f"-I{np.get_include()}", "-o", str(tmp), str(src_tmp), "-lm"],
                             capture_output=True, text=True)
        os.replace(src_tmp, src)
        if res.returncode != 0:
            notice("the CPython extension of the C kernels did not build (ctypes instead): "
                   + (res.stderr.strip().splitlines() or ["(no message)"])[-1])
            return False
        return True

    for attempt in range(2):
        lib = _build(name, f"the CPython extension of {source}", source, make)
        if lib is None:
            return None
        loader = importlib.machinery.ExtensionFileLoader(module, str(lib))
        spec = importlib.util.spec_from_file_location(module, lib, loader=loader)
        try:
            ext = importlib.util.module_from_spec(spec)
            loader.exec_module(ext)
            ext.set_error(InputError)
            return ext
        except Exception as exc:           # ImportError, or a module without set_error
            why = f"the CPython extension {lib} did not load ({type(exc).__name__}: {_first_line(exc)})"
            if attempt:
                notice(f"{why}: ctypes instead")
                return None
            _discard(name, why)
    return None


class KernelLoadError(DeriveError):
    """A kernel file of the cache or of generated/ that does not load (the loader derives the
    kernels again once, then raises it)."""


def _first_line(exc) -> str:
    return (str(exc).strip().splitlines() or [""])[0][:300]


def _import(path: Path, name: str):
    """Import a kernel module from its file; DeriveError (naming the file and the cause) when it
    does not import or lacks ``fk``."""
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception as exc:               # SyntaxError, TypeError, ... of a damaged file
        raise KernelLoadError(f"{path} did not import ({type(exc).__name__}: {_first_line(exc)})") from None
    if not callable(getattr(module, "fk", None)):
        raise KernelLoadError(f"{path} did not import (it defines no fk)")
    return module


def _rows(f, q: np.ndarray, width: int) -> np.ndarray:
    """f applied to each row of q (as a tuple), stacked into (n, width)."""
    return np.array([f(tuple(row)) for row in q.tolist()], dtype=float).reshape(-1, width)


class Kernels:
    """The kernels of one robot for one backend."""

    def __init__(self, robot, backend: str, free: str | None = None, nominal=None):
        self.robot = load_robot(robot)
        self.backend = backend
        self.dof = self.robot.dof
        #: the near-class arm's nominal robot and relation whose closed form the IK polishes, or None
        self.nominal = nominal
        if backend not in BACKENDS:
            raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
        folder, manifest = kernel_folder(self.robot, free, nominal=nominal)
        try:
            self._load(folder, manifest)
        except KernelLoadError as exc:     # a kernel file that does not load: derived again, once
            folder, manifest = kernel_folder(self.robot, free, rebuild=str(exc), nominal=nominal)
            self._load(folder, manifest)

    def _load(self, folder, manifest):
        """Load the backend's kernels from ``folder``; DeriveError when a file does not load."""
        backend = self.backend
        self._manifest = manifest
        files = manifest["files"]
        ident = manifest["prefix"]
        self.folder = folder
        self.free = manifest.get("free")   # the free parameter of a 7-joint arm's IK, else None
        #: the most solutions one pose has (8 for the closed forms, 16 for a general 6R and for
        #: near-class kernels of a 6R: derive.codegen.polish.polish_width)
        self.max_solutions = int(manifest.get("max_solutions", 8))
        if backend == "python":
            self._mod = _import(folder / files["python"],
                                f"{ident}_kinematics_{self.robot.id}_{self.robot.limits_id}")
        elif backend == "numpy":
            self._mod = _import(folder / files["numpy"],
                                f"{ident}_kinematics_numpy_{self.robot.id}_{self.robot.limits_id}")
        else:
            self._c_source, self._ident = folder / files["c_source"], ident
            try:
                text = self._c_source.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise KernelLoadError(f"{self._c_source} did not load (not readable as text: "
                                      f"{_first_line(exc)})") from None
            self._has_ik_c = "_ik_batch(" in text
            # kernels of an older dq-derive (no _ik_batch_ex) load through ctypes only
            if not self._has_ik_c or "_ik_batch_ex(" in text:
                self._ext = _extension(self.robot, self._c_source, ident, self._has_ik_c, self.free,
                                       self.max_solutions)
            if self._ext is None:
                self._load_ctypes()
            else:
                self._bind()

    def _q(self, Q):
        q = as_finite_array(Q, "Q", ndim_min=1)
        single = q.ndim == 1
        q2 = q[None, :] if single else q
        if q2.ndim != 2 or q2.shape[1] != self.dof:
            raise InputError(f"Q: expected shape ({self.dof},) or (n, {self.dof}), got {q.shape}")
        return np.ascontiguousarray(q2, dtype=np.float64), single

    _ext = None
    _tool = None

    def _load_ctypes(self):
        """The kernels' shared library through ctypes: the path without the extension (no Python
        headers), and :attr:`library` for callers who want the plain C functions."""
        if "_lib" in self.__dict__:
            return
        lib = _compile(self._c_source, self._ident)
        try:
            handle = ctypes.CDLL(str(lib))
        except OSError as exc:             # compiled again once, then DeriveError
            lib = _compile(self._c_source, self._ident,
                           again=f"the C library {lib} did not load ({_first_line(exc)})")
            try:
                handle = ctypes.CDLL(str(lib))
            except OSError as exc2:
                raise DeriveError(f"the C library {lib} did not load ({_first_line(exc2)})") from None
        self.__dict__["library"] = lib
        self._lib = handle
        f = getattr(self._lib, f"{self._ident}_fk_batch")
        f.argtypes = [ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p]
        f.restype = None
        self._fk_batch = f
        if hasattr(self._lib, f"{self._ident}_ik_batch"):
            g = getattr(self._lib, f"{self._ident}_ik_batch")
            g.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * (4 if self.free else 3)
            g.restype = None
            self._ik_batch = g

    def _bind(self):
        """The extension's bound ``fk`` and ``ik`` (``bind`` of templates/pyext.c.j2) in place of
        the methods on this instance: they run the plain call, ``fk(Q)`` and ``ik(P)`` (with
        ``free=`` for a 7-joint arm), in C with this instance's tool and without a Python frame
        (a few hundred ns of a single call), and hand any other call to the method."""
        for name in ("fk", "ik") if self._has_ik_c else ("fk",):
            self.__dict__[name] = self._ext.bind(name, self._tool, getattr(Kernels, name).__get__(self))

    @property
    def library(self) -> Path:
        """The compiled shared library of the C kernels (compiled on first use)."""
        self._load_ctypes()
        return self.__dict__["library"]

    def with_tool(self, tool) -> "Kernels":
        """The same kernels for the end frame moved by a fixed tool transform T (any pose form of
        :func:`derive.kinematics.pose.as_pose`): ``fk`` returns FK(q) T and ``ik`` solves poses of
        the tool frame (as P T^-1). No regeneration; ``with_tool(None)`` removes it."""
        k = copy.copy(self)
        k._tool = None if tool is None else as_pose(tool, "tool")
        if k._ext is not None:
            k._bind()
        return k

    def fk(self, Q) -> np.ndarray:
        """Unit dual quaternions (n, 8) of the end frame (sign as the product gives). With the C
        extension, ``k.fk`` is its bound fk (:meth:`_bind`), which comes here only for calls with
        keywords."""
        if self._ext is not None:
            return self._ext.fk(Q, self._tool)
        q, single = self._q(Q)
        if self.backend == "python":
            out = _rows(self._mod.fk, q, 8)
        elif self.backend == "numpy":
            out = self._mod.fk(q)
        else:
            out = np.empty((q.shape[0], 8))
            self._fk_batch(q.shape[0], q.ctypes.data, out.ctypes.data)
        if self._tool is not None:
            out = dq._mul(out, self._tool[None])
        return out[0] if single else out

    @property
    def has_ik(self) -> bool:
        if self.backend == "c":
            return self._has_ik_c
        return hasattr(self._mod, "ik")


    def _require_ik(self):
        if not self.has_ik:
            why = ("its fixed angles are not all multiples of pi/12, so there are no exact equations "
                   "to solve" if not self.robot.exact else
                   "the extraction found no closed form for this chain")
            r = self.robot
            seven = r.dof == 7 and all(j.type == "revolute" and not j.is_mimic for j in r.joints)
            raise DeriveError(f"{r.name}: no closed-form IK kernel ({why}); "
                              + (f"with a joint K given: derive.kernels({r.name!r}, {self.backend!r}, "
                                 "free='qK') (K = 1..7), or " if seven else "")
                              + "use derive.refine")

    def _check_free(self, free):
        """InputError unless ``free`` is given exactly when the arm has a free parameter."""
        if self.free and free is None:
            lo, hi = self.robot.limits[2]
            raise InputError(missing_free_message(self.robot) if self.free != "q3" else
                             f"{self.robot.name}: these kernels solve with joint 3 given and need "
                             f"free= (q3, the value of joint 3, rad, within its limits [{lo:.4g}, "
                             f"{hi:.4g}]), a number or one per pose")
        if free is not None and not self.free:
            raise InputError(f"free: {self.robot.name} has {self.dof} joints and no free parameter")

    def _windings(self, q, counts, branch, singular):
        """Every in-limit 2 pi winding of each solution, by the extension (in C, with the limits
        compiled into the kernel) or by :func:`derive.ik.select.within_limits`."""
        expand = None
        if self._ext is not None:
            def expand(cq, cc, cb, cg):
                return self._ext.within_limits(cq, np.asarray(cc, dtype=np.int64), np.asarray(cb, dtype=np.int64),
                                               np.asarray(cg, dtype=np.int64))
        # counted first, refused past select.MAX_RESULT_BYTES, expanded in chunks into the result
        return select.within_limits(q, counts, self.robot.limits, self.robot.revolute, branch, singular,
                                    expand=expand)

    def _require_main_free(self, what: str):
        """InputError for the searches over the free parameter on kernels that take joint 3."""
        if self.free == "q3":
            raise InputError(f"{what}: these kernels take q3; the search over the free parameter runs "
                             f"on the arm-angle kernels: derive.kernels({self.robot.name!r}, "
                             f"{self.backend!r}).{what}")

    def _ext_args(self, free) -> tuple:
        """The trailing arguments of the extension's ik / nearest: the free parameter, if any."""
        return (free,) if self.free else ()

    def ik(self, P, within_limits: bool = False, details: bool = False, free=None):
        """All closed-form solutions: (solutions (n, 8, dof) NaN-padded, counts (n,)).

        P: unit dual quaternions (n, 8) / (8,), matrices (n, 4, 4) / (4, 4) or [R | t] (n, 3, 4) /
        (3, 4), or a pair (R, t) (:func:`derive.kinematics.pose.as_pose_batch`) of the end frame
        (of the tool frame after :meth:`with_tool`); a pose farther than 1e-6 from unit (a
        rotation block farther than 1e-6 from orthonormal) raises InputError. At the wrist singularity the free joint is chosen as the generated file's
        header says.

        ``free``: a 7-joint arm's free parameter (:attr:`free`: the arm angle psi or q7, rad), a
        number or one per pose; required for those arms, refused for the others.

        ``details`` (C backend): also the branch index of each solution (which root each
        closed-form step took, :attr:`branch_labels`; -1 in the padding) and its singular flag:
        (solutions, counts, branch, singular). ``within_limits``: every in-limit winding of each
        solution (:func:`derive.ik.select.within_limits`), padded to the largest count of the
        call.

        With the C extension, ``k.ik`` is its bound ik (:meth:`_bind`): the plain call (poses as
        dual quaternions, ``free`` for a 7-joint arm, nothing else) runs in C, the input checked
        there, and every other call comes here."""
        self._check_free(free)
        self._require_ik()
        if details or within_limits:
            sols, counts, branch, sing = self._ik_details(P, need=details, free=free)
            single = sols.ndim == 2
            if within_limits:
                s3, c1 = (sols[None], np.atleast_1d(counts)) if single else (sols, counts)
                b3, g3 = (branch[None], sing[None]) if single else (branch, sing)
                sols3, cnt, b3, g3 = self._windings(s3, c1, b3, g3)
                sols, counts, branch, sing = ((sols3[0], int(cnt[0]), b3[0], g3[0]) if single
                                              else (sols3, cnt, b3, g3))
            return (sols, counts, branch, sing) if details else (sols, counts)
        if self._ext is not None:
            return self._ext_ik(P, False, free)
        poses, single = self._tool_free(P)
        n = poses.shape[0]
        fv = None if free is None else np.ascontiguousarray(redundant.free_values(free, n))
        if self.backend == "python":
            sols = np.full((n, self.max_solutions, self.dof), np.nan)
            counts = np.zeros(n, dtype=np.int64)
            for i, row in enumerate(poses.tolist()):
                found = self._mod.ik(row) if fv is None else self._mod.ik(row, float(fv[i]))
                counts[i] = len(found)
                if found:
                    sols[i, :len(found)] = found
        elif self.backend == "numpy":
            sols, counts = self._mod.ik(poses) if fv is None else self._mod.ik(poses, fv)
        else:
            sols = np.empty((n, self.max_solutions, self.dof))
            c = np.empty(n, dtype=np.intc)
            if fv is None:
                self._ik_batch(n, poses.ctypes.data, sols.ctypes.data, c.ctypes.data)
            else:
                self._ik_batch(n, poses.ctypes.data, fv.ctypes.data, sols.ctypes.data, c.ctypes.data)
            counts = c.astype(np.int64)
        return (sols[0], int(counts[0])) if single else (sols, counts)

    def _ik_details(self, P, need: bool, free=None):
        if self._ext is None:
            if need:
                raise DeriveError("ik(details=True) needs the C backend's extension "
                                  "(derive.kernels(robot, 'c') with the Python headers installed)")
            sols, counts = self.ik(P, free=free)
            shape = sols.shape[:-1]
            return sols, counts, np.full(shape, -1), np.zeros(shape, dtype=bool)
        return self._ext_ik(P, True, free)

    def _ext_ik(self, P, details: bool, free):
        """The extension's ik of poses P of the tool frame: dual quaternions and 4x4 / 3x4
        matrices are read, converted and checked in C, (R, t) pairs converted here first (the
        extension returns NotImplemented for them)."""
        out = self._ext.ik(P, self._tool, details, *self._ext_args(free))
        if out is NotImplemented:
            poses, single = as_pose_batch(P)
            out = self._ext.ik(poses[0] if single else poses, self._tool, details, *self._ext_args(free))
        return out

    def _tool_free(self, P):
        """Poses (n, 8) of the end frame for poses P of the tool frame (as P T^-1), and whether
        P was one pose."""
        poses, single = as_pose_batch(P)
        if self._tool is not None:
            poses = dq._mul(poses, dq.conj_quaternion(self._tool)[None])
        return np.ascontiguousarray(poses, dtype=np.float64), single

    def _solver(self, branch_ids: bool):
        """A 7-joint arm's IK at given free values as the solver of :mod:`derive.ik.redundant`:
        (poses (m, 8) of the end frame, free (m,)) -> (q, counts, branch, singular). The C
        extension gives branch ids; other backends give -1 there, and None when ``branch_ids``
        is required (the numpy closed form then searches)."""
        if self._ext is not None:
            return lambda poses, f: self._ext.ik(poses, None, True, np.ascontiguousarray(f, dtype=np.float64))
        if branch_ids:
            return None
        plain = self.with_tool(None)

        def solve(poses, f):
            q, counts = plain.ik(poses, free=f)
            shape = q.shape[:-1]
            return q, counts, np.full(shape, -1), np.zeros(shape, dtype=bool)
        return solve

    def ik_sweep(self, P, n: int, within_limits: bool = True) -> redundant.Sweep:
        """A 7-joint arm's solutions at ``n`` values of its free parameter over the feasible
        range of each pose (:func:`derive.ik.redundant.sweep_values`: joint 7's limits for the
        Panda class, the union of the pose's feasible arm-angle intervals, computed in closed
        form, for the SRS class), all values of all poses in one batch call of these kernels.
        Returns :class:`derive.ik.redundant.Sweep` (``free`` (P, n), ``q`` (P, n, K, 7), ``counts``,
        ``branch``, ``singular``); ``within_limits`` (default) keeps the in-limit windings only."""
        if not self.free:
            raise InputError(f"ik_sweep: {self.robot.name} has {self.dof} joints and no free parameter; use ik")
        self._require_main_free("ik_sweep")
        poses, single = self._tool_free(P)
        return redundant.ik_sweep(self.robot, poses[0] if single else poses, n,
                                  within_limits=within_limits, solver=self._solver(False), limiter=self._windings)

    def nearest(self, P, q_seed, tol=None) -> select.Nearest:
        """Per pose the solution nearest to the seed configuration(s) ``q_seed`` ((dof,) or (n,
        dof)): inside the joint limits with every winding, by the largest single-joint move, then
        the summed move (:func:`derive.ik.select.nearest`); ``found`` is False where no solution
        is within ``tol`` (rad or m) of the seed, or none is inside the limits. Where the chosen
        solution lies on a singular set, the free joint is the seed's (the reference solver
        re-solves those poses with the seed as reference configuration).

        A 7-joint arm's free parameter and branch are chosen by the 1-D search of
        :func:`derive.ik.redundant.nearest` (which keeps a path continuous), run on these kernels'
        batch IK with the C extension, else on the numpy closed form."""
        self._require_ik()
        if tol is not None and not (isinstance(tol, (int, float, np.floating, np.integer))
                                    and not isinstance(tol, bool) and math.isfinite(tol) and tol >= 0):
            raise InputError(f"tol: expected a finite number >= 0 (rad or m), got {tol!r}")
        if self.free:       # 7 joints: the free parameter and the branch by derive.ik.redundant's search
            self._require_main_free("nearest")
            poses, single = self._tool_free(P)
            return redundant.nearest(self.robot, poses[0] if single else poses, q_seed, tol,
                                     solver=self._solver(True))
        if self._ext is not None:               # IK and selection in one C pass (ik_nearest_batch)
            out = self._ext.nearest(P, q_seed, self._tool)
            if out is NotImplemented:
                poses, one = as_pose_batch(P)
                out = self._ext.nearest(poses[0] if one else poses, q_seed, self._tool)
            q, mx, tot, br, sg = out
            single = q.ndim == 1
            q, br, sg = np.atleast_2d(q), np.atleast_1d(br), np.atleast_1d(sg)
            found = br >= 0
            if tol is not None:
                found &= mx <= tol
            res = select.Nearest(q=np.where(found[:, None], q, np.nan), found=found,
                                 max_move=np.where(found, mx, np.nan), total_move=np.where(found, tot, np.nan),
                                 branch=np.where(found, br, -1), singular=found & (sg != 0))
        else:
            sols, counts, branch, sing = self._ik_details(P, need=False)
            single = sols.ndim == 2
            if single:
                sols, counts, branch, sing = sols[None], np.atleast_1d(counts), branch[None], sing[None]
            seeds = as_finite_array(q_seed, "q_seed", last_dim=self.dof)
            if seeds.ndim > 2 or (seeds.ndim == 2 and seeds.shape[0] not in (1, len(sols))):
                raise InputError(f"q_seed: expected shape ({self.dof},) or ({len(sols)}, {self.dof}) "
                                 f"(one seed, or one per pose), got {seeds.shape}")
            seeds = np.broadcast_to(seeds, (len(sols), self.dof))
            res = select.nearest(sols, counts, seeds, self.robot.limits, self.robot.revolute, branch, sing, tol)
        if np.any(res.singular) and self.nominal is None:     # (near-class: the polished solution stands)
            seeds = np.broadcast_to(np.asarray(q_seed, dtype=float), res.q.shape)   # checked above
            at = np.nonzero(res.singular)[0]
            poses = np.broadcast_to(self._tool_free(P)[0], (len(res.q), 8))[at]
            qs, cs = reference_ik_batch(self.robot, poses, q_ref=seeds[at])
            again = select.nearest(qs, cs, seeds[at], self.robot.limits, self.robot.revolute, tol=tol)
            q = res.q.copy()
            ok = again.found & (again.max_move <= res.max_move[at] + 1e-12)
            q[at[ok]] = again.q[ok]
            mx, tot = res.max_move.copy(), res.total_move.copy()
            mx[at[ok]], tot[at[ok]] = again.max_move[ok], again.total_move[ok]
            res = select.Nearest(q, res.found, mx, tot, res.branch, res.singular)
        if single:
            return select.Nearest(*(getattr(res, f)[0] for f in ("q", "found", "max_move", "total_move",
                                                               "branch", "singular")))
        return res

    def ik_polish(self, P, free=None):
        """Near-class kernels (``nominal=``): the solutions with their polish, (solutions (n, W,
        dof) NaN-padded, counts (n,), residual (n, W), iterations (n, W)), W = ``max_solutions``
        (the nominal's branches, then extra slots for the seeds' solutions): per solution its
        residual, the larger of the position error (m) and the rotation angle (rad) between the
        kernels' FK of it and the pose, and the Newton steps it took (NaN and -1 in the padding).
        ``free``: the given joint value of kernels that hold one (a 7-joint arm, ``free="q3"``)."""
        if self.nominal is None:
            raise DeriveError(f"{self.robot.name}: ik_polish is for near-class kernels "
                              "(derive.kernels(robot, backend, nominal=...))")
        self._check_free(free)
        poses, single = self._tool_free(P)
        n = poses.shape[0]
        fv = None if free is None else np.ascontiguousarray(redundant.free_values(free, n))
        extra = () if fv is None else (fv,)
        if self.backend == "python":
            w = self.max_solutions
            sols = np.full((n, w, self.dof), np.nan)
            counts = np.zeros(n, dtype=np.int64)
            res, its = np.full((n, w), np.nan), np.full((n, w), -1, dtype=np.int64)
            for i, row in enumerate(poses.tolist()):
                found = self._mod.ik_polish(row, *[float(x[i]) for x in extra])
                counts[i] = len(found)
                for k, (q, r, it) in enumerate(found):
                    sols[i, k], res[i, k], its[i, k] = q, r, it
        elif self.backend == "numpy":
            sols, counts, res, its = self._mod.ik_polish(poses, *extra)
        else:
            if not hasattr(self, "_ik_polish"):
                # the extension module holds the kernel source's functions too (pyext.c.j2
                # includes it): ctypes on its file, so that the kernel is not compiled a second
                # time; without the extension, the kernels' own library
                if self._ext is not None and getattr(self._ext, "__file__", None):
                    lib = ctypes.CDLL(self._ext.__file__)
                else:
                    self._load_ctypes()
                    lib = self._lib
                g = getattr(lib, f"{self._ident}_ik_batch_polish")
                g.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * (8 if self.free else 7)
                g.restype = None
                self._ik_polish = g
            w = self.max_solutions
            sols, res = np.empty((n, w, self.dof)), np.empty((n, w))
            c, it = np.empty(n, dtype=np.intc), np.empty((n, w), dtype=np.intc)
            self._ik_polish(n, poses.ctypes.data, *[x.ctypes.data for x in extra], sols.ctypes.data,
                            c.ctypes.data, None, None, res.ctypes.data, it.ctypes.data)
            counts, its = c.astype(np.int64), it.astype(np.int64)
        if single:
            return sols[0], int(counts[0]), res[0], its[0]
        return sols, counts, res, its

    @property
    def branch_labels(self) -> list:
        """The closed-form steps whose roots the bits of a branch index choose, most significant first."""
        return list(self._manifest.get("branch_labels", [])) if self.has_ik else []


def near_class_nominal(robot, free: str | None = None):
    """The :class:`derive.ik.nearclass.Nominal` that :func:`kernels` uses for ``robot`` when
    none is given: None for a robot whose kernels ship in generated/ or that has an exact class
    (:func:`derive.ik.nearclass.nominal`), and for a 7-joint arm without ``free`` (the near-class
    polish holds a joint, ``free="q3"``, not the arm angle). ``derive.ik.nearclass`` is imported
    here, on first need, so that loading shipped kernels stays light."""
    if shipped_index().get(robot.id) is not None or (robot.dof == 7 and free is None):
        return None
    from derive.ik import nearclass
    return nearclass.nominal(robot)


def _any_joint(robot, free) -> bool:
    """Whether ``free`` is "qK" for a 7R arm and not one of its class's own choices
    (:data:`derive.ik.redundant.FREE_CHOICES`, kept by the generated kernels) nor a near-class
    arm's q3 (the polish kernels)."""
    if free is None or robot.dof != 7:
        return False
    from derive.ik.free_joint import parse_joint
    if parse_joint(free) is None:
        return False
    if free in redundant.FREE_CHOICES.get(redundant.redundant_kind(robot), ()):
        return False
    # a near-class SRS arm's q3 stays with its nominal's polish kernels
    return not (free == "q3" and near_class_nominal(robot, free) is not None)


def kernels(robot, backend: str = "numpy", free: str | None = None, nominal=None) -> Kernels:
    """The generated kernels of ``robot`` (a library name, a description file under any name,
    or a :class:`~derive.model.robot.Robot`) for ``backend`` ("python", "numpy", "c"), loaded
    from the artifacts of its identity (see :func:`kernel_folder`); once per process.

    ``free``: for a 7-joint arm, which free parameter the IK takes where the class offers a
    choice (:data:`derive.ik.redundant.FREE_CHOICES`): the SRS class (iiwa) takes the arm angle
    psi by default and joint 3's value with ``free="q3"`` (derived into the user cache on first
    use, about 15 s; ``ik_sweep`` and ``nearest`` search over psi: use the default kernels for
    them; CasADi: ``functions(robot)["ik_q3"]``). Any other ``free="qK"`` (K = 1..7) of a
    7-joint arm: :class:`derive.codegen.free_joint.FreeJointKernels`, the IK with joint K given
    by :mod:`derive.ik.free_joint` (numpy; "python" and "numpy" backends: the class's closed form
    where :func:`derive.ik.free_joint.route` names one, else the general 6R). The "c" backend runs
    the class's IK program on the SRS class routes (q1, q2, q5, q6, q7:
    :func:`derive.ik.program7.srs_joint_program`, printed as the generated kernels print it), else
    templates/free_joint.c.j2, the general 6R elimination, where it has a plan
    (:func:`derive.ik.free_joint.plan`); the SRS class's q4 is refused for every backend.

    ``nominal``: a near-class arm's :class:`derive.ik.nearclass.Nominal` (its exact nominal robot
    and the relation FK(q) ~= B FK_nominal(s q + o) T): the IK runs the nominal's closed form and
    polishes every candidate by Newton steps on the robot's own FK (:mod:`derive.codegen.polish`;
    :meth:`Kernels.ik_polish` gives the residuals); derived into the user cache on first use.
    Without it, a near-class arm's nominal is found by :func:`near_class_nominal`."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    r = load_robot(robot)
    if nominal is None and _any_joint(r, free):
        # any joint K of a 7R arm outside its class's own choices: derive.ik.free_joint (numpy)
        k = int(free[1:])
        # a class route (SRS q1, q2, q5, q6, q7): the C is the class's IK program (no plan needed)
        from derive.codegen.free_joint import free_joint_kernels
        return memo("kernels-free-joint", (r.id, r.limits_id, backend, k),
                    lambda: free_joint_kernels(r, backend, k, kernels(r, backend), _compile))
    if nominal is None:
        nominal = near_class_nominal(r, free)
    free = free_choice(r if nominal is None else nominal.robot, free)
    key = (r.id, r.limits_id, backend, tuple(c_flags()) if backend == "c" else (), free,
           None if nominal is None else nominal_key(nominal))
    return memo("kernels", key, lambda: Kernels(r, backend, free, nominal))
