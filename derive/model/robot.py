"""Robot descriptions: the YAML file format, its validation, and the robot library.

A description names a kinematic convention and lists the joints; the format is
documented in ``docs/robot-format.md``. Whatever the convention, each joint is
reduced here to one neutral form that both reference implementations (dual
quaternions and 4x4 matrices) evaluate on their own:

    T_joint(q) = pre_1 ... pre_k  Motion(axis, q + offset)  post_1 ... post_m

where every ``pre``/``post`` is an elementary operation ("R", axis, angle) or
("T", vector) and Motion is a rotation (revolute) or translation (prismatic)
along a unit axis of the parent frame.

Conventions (theta_i, d_i, a_i, alpha_i the joint's DH numbers):

* ``standard_dh``:  T = Rz(theta) Tz(d) Tx(a) Rx(alpha)  (Kunze eq. 5.3-5.4)
* ``kunze``:        the same product written with s for d: QDH(theta, s, a, alpha) (Kunze eq. 5.7)
* ``modified_dh``:  T = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i)  (Craig); the file gives
  each joint the alpha and a of the link before it
* ``axis_angle``:   each joint's axis and link vector in the base frame at the reference
  configuration, where every joint value is zero (thesis section 4.2.1, seed 001 eq. 10-11):
  T = Rot(axis, theta) Trans(link). The joint axis passes through the parent frame's origin.
* ``urdf``:         the URDF joint form (ROS REP 103 / the URDF specification): each joint's
  ``origin``, one or a list of fixed transforms {translation, rotation} applied in order (a
  URDF joint's origin, with the fixed joints before it folded in), then the motion along
  ``axis`` in the joint frame, then the optional ``after`` list (fixed transforms past the
  motion, in the joint's own frame; a URDF has none, the export of another convention needs
  them): T = Origin_1 ... Origin_k Motion(axis, q) After_1 ... After_m. URDF files are read
  into this form by :mod:`derive.model.urdf`, and :mod:`derive.model.export` writes any robot
  in it.
"""

from __future__ import annotations

import ast
import math
import operator
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

# the package, not derive.model.urdf: the URDF reader (lxml, yourdfpy) is imported on first use
# through the package's attribute (derive/model/__init__.py), so loading a YAML or library
# robot does not import it
import derive.model as model
from derive.cache import memo
from derive.errors import RobotFileError, UnknownRobotError
from derive.model.identity import digest, limits_digest

LIBRARY_DIR = Path(__file__).resolve().parent.parent / "robots"

CONVENTIONS = ("standard_dh", "modified_dh", "kunze", "axis_angle", "urdf")
JOINT_TYPES = ("revolute", "prismatic")
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}

#: A length above this many metres in a file declared in metres is taken for a unit mistake.
MAX_LENGTH_M = 20.0
#: A fixed angle (alpha, theta, offset) above this many radians is taken for degrees.
MAX_ANGLE_RAD = 2.0 * math.pi + 1e-9
#: Joint limits beyond this many radians are taken for degrees.
MAX_LIMIT_RAD = 8.0 * math.pi
#: A fixed angle given as a decimal number within this many radians of a multiple of pi/12
#: is that multiple (1.5707963267948966 is pi/2): the rounding of a printed constant, not a
#: deviation. Farther off, the number is kept as it is and the robot is not exact.
SNAP_TOL = 1e-12
#: Robot names: also the folder name of its outputs (``--out DIR`` writes DIR/<name>/).
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")

_DH_KEYS = {
    "standard_dh": ("theta", "d", "a", "alpha"),
    "modified_dh": ("alpha", "a", "theta", "d"),
    "kunze": ("theta", "s", "a", "alpha"),
}
_ANGLE_FIELDS = {"theta", "alpha"}
_COMMON_JOINT_KEYS = {"name", "type", "offset", "limits", "parent", "mimic", "description"}

EX, EY, EZ = np.eye(3)


# --------------------------------------------------------------------------- #
# Data model
# --------------------------------------------------------------------------- #
class Num(float):
    """A float read from a description file that also carries the ``recipe`` of its exact
    value: a sympy expression in SI units over the file's named parameters (``d1``, ``a2``,
    ...), with exact rationals and pi, which :func:`derive.model.exact.value` builds when the
    symbolic derivation asks for it (reading a robot does not import sympy). The numeric code
    sees a plain float. Recipes: ``("field", raw, kind, context)`` (a field as written, kind
    "length", "angle" or "unitless"), ``("unit", components, k)`` (component k of a
    normalised axis), ``("turn", angle)`` (the angle of a rotation given as a quaternion)."""

    recipe: tuple

    def __new__(cls, value, recipe):
        obj = super().__new__(cls, value)
        obj.recipe = recipe
        return obj

    def __reduce__(self):
        # pickled with its recipe (a Robot sent to another process: Dask workers of reach/place)
        return (type(self), (float(self), self.recipe))


@dataclass(frozen=True)
class Op:
    """Elementary rigid motion: ``kind`` "R" (rotation by ``angle`` about unit
    ``axis``) or "T" (translation by ``vector``). ``numbers`` holds the numbers as read
    (:class:`Num` or plain floats): (axis, angle) for "R", the vector for "T"; their exact
    form is :func:`derive.model.exact.op_form`."""

    kind: str
    axis: np.ndarray | None = None
    angle: float = 0.0
    vector: np.ndarray | None = None
    numbers: tuple = ()

    @staticmethod
    def rot(axis, angle) -> "Op":
        return Op("R", axis=np.asarray(axis, dtype=float), angle=float(angle),
                  numbers=(tuple(axis), angle))

    @staticmethod
    def trans(vector) -> "Op":
        return Op("T", vector=np.asarray(vector, dtype=float), numbers=tuple(vector))


@dataclass(frozen=True)
class Joint:
    """One joint of the tree, in the neutral form described in the module docstring."""

    name: str
    type: str                      # "revolute" or "prismatic"
    parent: int                    # index of the parent joint, -1 for the base
    axis: np.ndarray               # unit motion axis in the parent frame (after ``pre``)
                                   # (its exact form: derive.model.exact.joint_axis)
    pre: tuple[Op, ...]
    post: tuple[Op, ...]
    offset: float                  # added to the joint value (rad or m); a Num (exact: model.exact)
    limits: tuple[float, float] | None
    variable: int                  # index into q of the variable that drives this joint
    multiplier: float = 1.0        # joint value = multiplier * q[variable] + mimic_offset
    mimic_offset: float = 0.0
    params: dict = field(default_factory=dict)   # the file's fields, as written
    axis_numbers: tuple = ()       # the motion axis as read (Num or float; exact: model.exact)

    @property
    def is_mimic(self) -> bool:
        return self.params.get("mimic") is not None


@dataclass(frozen=True)
class End:
    """A named end frame: a fixed transform (translation then rotation) after ``parent``."""

    name: str
    parent: int
    ops: tuple[Op, ...]


@dataclass(frozen=True)
class Robot:
    """A loaded, validated robot description (lengths in metres, angles in radians)."""

    name: str
    title: str
    source: str
    convention: str
    joints: tuple[Joint, ...]
    ends: dict
    default_end: str
    parameters: dict
    path: str
    notes: str = ""
    nominal: str = ""              # library robot whose closed form seeds this one (calibrated arms)
    exact: bool = True             # every fixed angle a multiple of pi/12 (see is_exact)
    id: str = ""                   # identity: hash of the normalised description (model.identity)

    @property
    def dof(self) -> int:
        """Number of independent joint variables (mimic joints excluded)."""
        return sum(1 for j in self.joints if not j.is_mimic)

    @property
    def variable_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints if not j.is_mimic)

    @property
    def frame_names(self) -> tuple[str, ...]:
        """Frames reported by :func:`derive.reference.joint_positions`: base, joints, ends."""
        return ("base",) + tuple(j.name for j in self.joints) + tuple(self.ends)

    @property
    def limits(self) -> np.ndarray:
        """(dof, 2) array of joint limits; +-inf where the file gives none."""
        out = []
        for j in self.joints:
            if not j.is_mimic:
                out.append(j.limits if j.limits is not None else (-math.inf, math.inf))
        return np.array(out, dtype=float).reshape(-1, 2)

    @property
    def limits_id(self) -> str:
        """The key part of the joint limits (:func:`derive.model.identity.limits_digest`), which
        ``id`` leaves out: artifacts that embed the limits (the kernels) are keyed by both."""
        return limits_digest(self.joints)

    @property
    def revolute(self) -> np.ndarray:
        """(dof,) bool: which joint variables are revolute (their values wind by 2 pi)."""
        return np.array([j.type == "revolute" for j in self.joints if not j.is_mimic], dtype=bool)

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, {self.convention}, dof={self.dof}, ends={list(self.ends)})"


# --------------------------------------------------------------------------- #
# Safe arithmetic for fields such as "pi/2" or "-d4"
# --------------------------------------------------------------------------- #
_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow}
_UNOPS = {ast.USub: operator.neg, ast.UAdd: operator.pos}
#: Longest expression a numeric field may hold (characters).
MAX_EXPRESSION_CHARS = 200
#: Largest exponent (in size) of ** in a numeric field.
MAX_EXPONENT = 64


class _Expr:
    """Evaluate a numeric field: a number, or an expression over pi and parameters."""

    def __init__(self, where: str, parameters: dict, degrees: bool):
        self.where = where
        self.parameters = parameters
        self.degrees = degrees
        self.used: set[str] = set()

    def __call__(self, value, what: str) -> float:
        if isinstance(value, bool) or value is None:
            raise RobotFileError(f"{self.where}: {what} must be a number, got {value!r}")
        if isinstance(value, (int, float)):
            try:
                result = float(value)
            except OverflowError:
                result = math.inf
            if not math.isfinite(result):
                raise RobotFileError(f"{self.where}: {what} = {_short(value)} is not finite")
            return result
        if not isinstance(value, str):
            raise RobotFileError(f"{self.where}: {what} must be a number or expression, got {value!r}")
        if len(value) > MAX_EXPRESSION_CHARS:
            raise RobotFileError(f"{self.where}: {what} = {_short(value)} is longer than "
                                 f"{MAX_EXPRESSION_CHARS} characters; write the number")
        try:
            tree = ast.parse(value.strip(), mode="eval")
        except (SyntaxError, ValueError, MemoryError, RecursionError):
            raise RobotFileError(f"{self.where}: {what} = {value!r} is not a valid expression") from None
        result = self._eval(tree.body, value, what)
        if not math.isfinite(result):
            raise RobotFileError(f"{self.where}: {what} = {value!r} is not finite")
        return result

    def _eval(self, node, text, what):
        """The value of ``node`` as a float: every constant and every intermediate result is a
        finite float (an exact integer is never formed, so ``10**10**10`` cannot hang), and an
        exponent is at most MAX_EXPONENT in size; anything else is a RobotFileError naming the
        file, the joint and the field."""
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                and not isinstance(node.value, bool):
            try:
                value = float(node.value)
            except OverflowError:
                value = math.inf
            return self._finite(value, text, what)
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            left = self._eval(node.left, text, what)
            right = self._eval(node.right, text, what)
            if isinstance(node.op, ast.Pow):
                if abs(right) > MAX_EXPONENT:
                    raise RobotFileError(f"{self.where}: {what} = {_short(text)}: the exponent {right:g} "
                                         f"is larger than {MAX_EXPONENT} in size")
                if left < 0 and right != int(right):
                    raise RobotFileError(f"{self.where}: {what} = {_short(text)}: a negative number to a "
                                         "non-integer power is not a real number")
            try:
                value = _BINOPS[type(node.op)](left, right)
            except ZeroDivisionError:
                raise RobotFileError(f"{self.where}: {what} = {_short(text)} divides by zero") from None
            except OverflowError:
                value = math.inf
            if isinstance(value, complex):        # not reachable after the checks above; kept total
                raise RobotFileError(f"{self.where}: {what} = {_short(text)} is not a real number")
            return self._finite(value, text, what)
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNOPS:
            return _UNOPS[type(node.op)](self._eval(node.operand, text, what))
        if isinstance(node, ast.Name):
            if node.id == "pi":
                if self.degrees:
                    raise RobotFileError(
                        f"{self.where}: {what} = {text!r} uses pi but the file's angle unit is "
                        "deg; write degrees or set units.angle: rad")
                return math.pi
            if node.id in self.parameters:
                self.used.add(node.id)
                return self.parameters[node.id]
            raise RobotFileError(f"{self.where}: {what} = {text!r} uses unknown name {node.id!r} "
                                 f"(known: pi, {', '.join(sorted(self.parameters)) or 'no parameters'})")
        raise RobotFileError(f"{self.where}: {what} = {_short(text)}: only numbers, pi, parameters "
                             "and + - * / ** are allowed")

    def _finite(self, value: float, text, what) -> float:
        if not math.isfinite(value):
            raise RobotFileError(f"{self.where}: {what} = {_short(text)} is not finite (beyond the "
                                 "range of a float)")
        return value


def _short(text) -> str:
    """repr of a field for a message, cut to 60 characters."""
    if isinstance(text, int) and not isinstance(text, bool) and text.bit_length() > 180:
        return f"an integer of about {int(text.bit_length() * 0.30103) + 1} digits"
    r = repr(text)
    return r if len(r) <= 60 else r[:57] + "..."


# --------------------------------------------------------------------------- #
# Loading
# --------------------------------------------------------------------------- #
def list_robots() -> list[str]:
    """Names of the robots shipped in the library, sorted."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.yaml"))


def load_robot(name_or_path, base: str | None = None, tip: str | None = None) -> Robot:
    """Load a robot by library name (``"ur5"``) or from a description file path: our YAML
    (``.yaml``/``.yml``, docs/robot-format.md) or a URDF (``.urdf``; ``base`` and ``tip`` name
    the links of the chain, by default the root link and the single leaf, see
    :mod:`derive.model.urdf`; ``tip`` a list of links reads the tree of their chains, each tip
    an end frame).

    Which one (docs/robot-format.md, "Library names and file paths"): a bare name (no path
    separator, no extension) is a library robot, even where the current folder holds a file of
    that name; a file needs a path with a separator or an extension (``./ur5``, ``arm.yaml``) or
    a :class:`pathlib.Path`. A text that reads both ways and finds both, a library robot and an
    existing file (a ``Path("ur5")`` beside a file ``ur5``), is refused with
    :class:`~derive.errors.UnknownRobotError` naming both (:func:`resolve_name`)."""
    if isinstance(name_or_path, Robot):
        return name_or_path
    if not isinstance(name_or_path, (str, Path)):
        raise UnknownRobotError(f"robot must be a name or a path, got {type(name_or_path).__name__}")
    text = str(name_or_path)
    path = Path(text)
    if text.endswith(".xacro"):
        raise RobotFileError(f"{text}: xacro files are not read; expand it first: "
                             f"xacro {path.name} > {path.name.removesuffix('.xacro').removesuffix('.urdf')}.urdf")
    kind = resolve_name(name_or_path)
    if kind == "file":
        if path.suffix == ".urdf" or (path.suffix not in (".yaml", ".yml") and _looks_like_xml(path)):
            if isinstance(tip, (list, tuple)):
                tip = tuple(tip)
            return _load_file(str(path.resolve()), base, tip, urdf=True)
        if base is not None or tip is not None:
            raise RobotFileError(f"{text}: base and tip select the chain of a URDF; this is a YAML file")
        return _load_file(str(path.resolve()), urdf=False)
    if base is not None or tip is not None:
        raise RobotFileError(f"{text}: base and tip select the chain of a URDF file, not of a library robot")
    return _load_file(str(LIBRARY_DIR / f"{text}.yaml"), urdf=False)


def _is_path_form(name_or_path) -> bool:
    """True for a :class:`pathlib.Path` and for a text with a path separator or an extension."""
    if isinstance(name_or_path, Path):
        return True
    text = str(name_or_path)
    seps = {"/", os.sep, os.altsep} - {None}
    return any(s in text for s in seps) or Path(text).suffix != ""


def resolve_name(name_or_path) -> str:
    """"library" or "file": how :func:`load_robot` reads a name or path (docs/robot-format.md,
    "Library names and file paths"), or UnknownRobotError.

    * a bare name (a text without a path separator or an extension) is a library robot; when
      the library has no robot of that name the error says so, and names the file of that name
      in the current folder if there is one (``./NAME`` loads it);
    * a text with a separator or an extension, and a :class:`pathlib.Path`, is a file path; a
      missing file is an error (which names the library robot of the same stem, if any);
    * ambiguous, an error naming both: a path form that is also a library name, where the file
      exists too (``Path("ur5")`` in a folder with a file ``ur5``; a library name with a dot
      beside a file of that name)."""
    text = str(name_or_path)
    path = Path(text)
    library = list_robots()
    in_library = text in library
    if not _is_path_form(name_or_path):
        if in_library:
            return "library"
        hint = ""
        if path.is_file():
            hint = (f". A bare name is a library robot; the file {text!r} in the current folder "
                    f"loads as './{text}' (a file needs a path with a separator or an extension)")
        raise UnknownRobotError(f"unknown robot {text!r}; the library has: {', '.join(library)}{hint}")
    if path.is_file():
        if in_library:
            raise UnknownRobotError(
                f"{text!r} is ambiguous: it names the library robot {text!r} "
                f"({LIBRARY_DIR / (text + '.yaml')}) and the file {path.resolve()}; pass the string "
                f"{text!r} for the library robot, or the file's path with a separator "
                f"({str(path.resolve())!r}) for the file")
        return "file"
    if in_library:
        return "library"
    hint = ""
    stem = path.name.removesuffix(path.suffix) if path.suffix in (".yaml", ".yml", ".urdf") else ""
    if stem in library and path.parent == Path("."):
        hint = f" (the library robot of that name loads as {stem!r}, without the extension)"
    raise UnknownRobotError(f"robot file {text!r} does not exist{hint}")


def _looks_like_xml(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return fh.read(200).lstrip().startswith("<")
    except OSError:
        return False


def _load_file(path: str, base: str | None = None, tip: str | None = None, urdf: bool = False) -> Robot:
    """Read a description file; parsed once per (path, content, base, tip), so an edited file
    is read anew."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as exc:
        raise RobotFileError(f"{path}: cannot be read ({exc.strerror})") from None
    return memo("robot-file", (path, text, base, tip, urdf), lambda: _parse(path, text, base, tip, urdf))


#: PyYAML's safe loader, the libyaml (C) parser where PyYAML has it (ten times faster: the
#: library's files are read in classify's search for a related robot).
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _parse(path: str, text: str, base, tip, urdf: bool) -> Robot:
    if urdf:
        return robot_from_dict(model.urdf.urdf_description(path, text, base, tip), path)
    try:
        data = yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as exc:
        raise RobotFileError(f"{path}: not valid YAML ({exc})") from None
    except (ValueError, OverflowError, RecursionError) as exc:     # e.g. an integer of > 4300 digits
        raise RobotFileError(f"{path}: a value cannot be read ({str(exc)[:120]})") from None
    return robot_from_dict(data, path)


def robot_from_dict(data: Any, path: str = "<dict>") -> Robot:
    """Validate a parsed description and build a :class:`Robot`."""
    where = Path(path).name if path != "<dict>" else path
    if not isinstance(data, dict):
        raise RobotFileError(f"{where}: the top level must be a mapping, got {type(data).__name__}")
    allowed = {"name", "title", "source", "notes", "nominal", "convention", "units", "parameters", "joints",
               "tool", "ends", "default_end"}
    unknown = set(data) - allowed
    if unknown:
        raise RobotFileError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    for key in ("name", "convention", "joints"):
        if key not in data:
            raise RobotFileError(f"{where}: missing required key {key!r}")
    name = data["name"]
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise RobotFileError(f"{where}: name {name!r} must be letters, digits, '_', '.' or '-', "
                             "starting with a letter or digit (it names the output folder)")
    conv = data["convention"]
    if conv not in CONVENTIONS:
        raise RobotFileError(f"{where}: convention {conv!r} is not one of {CONVENTIONS}")

    units = data.get("units") or {}
    if not isinstance(units, dict) or set(units) - {"length", "angle"}:
        raise RobotFileError(f"{where}: 'units' must be a mapping with keys length and angle")
    lu, au = units.get("length", "m"), units.get("angle", "rad")
    if lu not in LENGTH_UNITS:
        raise RobotFileError(f"{where}: unknown length unit {lu!r}; use one of {sorted(LENGTH_UNITS)}")
    if au not in ANGLE_UNITS:
        raise RobotFileError(f"{where}: unknown angle unit {au!r}; use one of {sorted(ANGLE_UNITS)}")

    params_raw = data.get("parameters") or {}
    if not isinstance(params_raw, dict):
        raise RobotFileError(f"{where}: 'parameters' must be a mapping of names to numbers")
    params: dict[str, float] = {}
    for k, v in params_raw.items():
        if not isinstance(k, str) or not k.isidentifier() or k == "pi":
            raise RobotFileError(f"{where}: parameter name {k!r} is not a valid identifier")
        params[k] = _Expr(f"{where}: parameters", {}, au == "deg")(v, k)

    joints_raw = data["joints"]
    if not isinstance(joints_raw, list) or not joints_raw:
        raise RobotFileError(f"{where}: 'joints' must be a non-empty list")

    ctx = _Context(where, conv, params, lu, au, params_raw)
    joints: list[Joint] = []
    names: dict[str, int] = {}
    nvar = 0
    for i, jr in enumerate(joints_raw):
        j = ctx.joint(i, jr, names, joints, nvar)
        if j.name in names:
            raise RobotFileError(f"{where}: joint name {j.name!r} is used twice")
        names[j.name] = i
        joints.append(j)
        if not j.is_mimic:
            nvar += 1
    # Resolve mimic joints now that every joint has its variable index.
    joints = [ctx.resolve_mimic(j, names, joints) for j in joints]

    ends: dict[str, End] = {}
    last = len(joints) - 1
    tool = data.get("tool")
    ends_raw = data.get("ends") or {}
    if not isinstance(ends_raw, dict):
        raise RobotFileError(f"{where}: 'ends' must be a mapping of end names to transforms")
    if tool is not None:
        ends["tool"] = End("tool", last, ctx.fixed(tool, "tool"))
    for en, er in ends_raw.items():
        if en in ends or en in names or en == "base":
            raise RobotFileError(f"{where}: end name {en!r} clashes with another frame")
        if not isinstance(er, dict):
            raise RobotFileError(f"{where}: ends.{en} must be a mapping")
        parent = er.get("parent", joints[last].name)
        if parent not in names:
            raise RobotFileError(f"{where}: ends.{en}.parent {parent!r} is not a joint name")
        if "origin" in er and set(er) - {"parent", "origin"}:
            raise RobotFileError(f"{where}: ends.{en}: give 'origin' (a list of transforms) or "
                                 "'translation' / 'rotation', not both")
        body = er["origin"] if "origin" in er else {k: v for k, v in er.items() if k != "parent"}
        ends[str(en)] = End(str(en), names[parent], ctx.fixed(body, f"ends.{en}"))
    if not ends:
        ends["flange"] = End("flange", last, ())
    default_end = data.get("default_end", next(iter(ends)))
    if default_end not in ends:
        raise RobotFileError(f"{where}: default_end {default_end!r} is not one of {list(ends)}")

    unused = set(params) - ctx.used
    if unused:
        raise RobotFileError(f"{where}: parameter(s) {sorted(unused)} are defined but never used")
    params_si = {k: params[k] * ctx.param_factor(k) for k in params}

    joints = tuple(joints)
    exact = is_exact(joints, ends)
    return Robot(name=name, title=str(data.get("title", name)), source=str(data.get("source", "")),
                 convention=conv, joints=joints, ends=ends, default_end=default_end,
                 parameters=params_si, path=path, notes=str(data.get("notes", "")),
                 nominal=_nominal(data.get("nominal"), where), exact=exact,
                 id=digest(joints, ends, default_end, exact))


def is_exact(joints, ends) -> bool:
    """Whether every fixed angle of a description (twists, offsets, fixed rotations of the
    joints and end frames) is a multiple of pi/12 (15 degrees), so that the joint dual
    quaternions have the exact cos/sin values (radicals) the symbolic derivation folds. A robot that is not exact
    (decimal or calibrated angles) gets its kernels from the numeric product instead
    (:mod:`derive.codegen.fk`)."""
    ops = [op for j in joints for op in (*j.pre, *j.post)] + [op for e in ends.values() for op in e.ops]
    angles = [op.numbers[1] for op in ops if op.kind == "R"]
    angles += [j.offset for j in joints if j.type == "revolute"]
    return all(_exact_multiple(a) for a in angles)


def _exact_multiple(angle) -> bool:
    """Whether the exact value of a fixed angle (:func:`derive.model.exact.value`) is a multiple
    of pi/12, decided without building it: an angle read from a file (a field, or the angle of
    a quaternion) is a multiple exactly when its number is within SNAP_TOL of one (it is then
    that multiple; farther off it stays the float, see :func:`derive.model.exact.value`); a
    plain float is made rational, a multiple of pi/12 only when it is 0."""
    if isinstance(angle, Num) and angle.recipe[0] in ("field", "turn"):
        return snap_multiple(float(angle)) is not None
    return float(angle) == 0.0


def snap_multiple(value: float) -> int | None:
    """k when ``value`` (rad) is within SNAP_TOL of k pi / 12, else None."""
    k = round(value / (math.pi / 12))
    if abs(value - k * math.pi / 12) <= SNAP_TOL:
        return k
    return None


def _nominal(value, where: str) -> str:
    """The ``nominal`` key: a library robot name (checked to exist)."""
    if value is None:
        return ""
    if not isinstance(value, str) or value not in list_robots():
        raise RobotFileError(f"{where}: nominal {value!r} is not a robot of the library "
                             f"({', '.join(list_robots())})")
    return value


class _Context:
    """Per-file state while joints are read: units, parameters, parameter kinds."""

    def __init__(self, where, conv, params, lu, au, params_raw=None):
        self.where, self.conv, self.params = where, conv, params
        self.params_raw = params_raw or {}
        self.lf, self.af, self.degrees = LENGTH_UNITS[lu], ANGLE_UNITS[au], au == "deg"
        self.length_unit, self.angle_unit = lu, au     # for the exact values (derive.model.exact)
        self.used: set[str] = set()
        self.kind_of: dict[str, str] = {}

    def param_factor(self, name):
        return self.af if self.kind_of.get(name) == "angle" else self.lf

    # -- scalar fields -------------------------------------------------------
    def _value(self, where, raw, what, kind):
        ev = _Expr(where, self.params, self.degrees)
        v = ev(raw, what)
        for p in ev.used:
            if self.kind_of.setdefault(p, kind) != kind:
                raise RobotFileError(f"{where}: parameter {p!r} is used both as a length and an angle")
        self.used |= ev.used
        # the exact value is built from the field as written when asked for
        # (derive.model.exact.value; the context's parameter kinds are complete by then)
        return Num(v, ("field", raw, kind, self))

    def _scaled(self, where, raw, what, kind, limit, unit, hint):
        v = self._value(where, raw, what, kind)
        v = Num(v * (self.lf if kind == "length" else self.af), v.recipe)
        if abs(v) > limit:
            raise RobotFileError(f"{where}: {what} = {v:g} {unit} is out of range; {hint}")
        return v

    def length(self, where, raw, what):
        return self._scaled(where, raw, what, "length", MAX_LENGTH_M, "m",
                            "is the file in millimetres? set units.length: mm")

    def angle(self, where, raw, what, limit=MAX_ANGLE_RAD):
        return self._scaled(where, raw, what, "angle", limit, "rad",
                            "is it in degrees? set units.angle: deg")

    def vector(self, where, raw, what, kind="length"):
        if not isinstance(raw, (list, tuple)) or len(raw) != 3:
            raise RobotFileError(f"{where}: {what} must be a list of 3 numbers, got {raw!r}")
        if kind == "length":
            return [self.length(where, x, f"{what}[{k}]") for k, x in enumerate(raw)]
        return [self._value(where, x, f"{what}[{k}]", "unitless") for k, x in enumerate(raw)]

    def axis(self, where, raw, what="axis"):
        v = self.vector(where, raw, what, kind="unitless")
        n = float(np.linalg.norm(np.array(v, dtype=float)))
        if n < 1e-9:
            raise RobotFileError(f"{where}: {what} is the zero vector; a joint axis needs a direction")
        if abs(n - 1.0) > 1e-6:
            raise RobotFileError(f"{where}: {what} = {raw!r} has length {n:.6g}; give a unit vector")
        return [Num(float(x) / n, ("unit", tuple(v), k)) for k, x in enumerate(v)]

    # -- joints --------------------------------------------------------------
    def joint(self, i, jr, names, joints, nvar) -> Joint:
        where = f"{self.where}: joints[{i}]"
        if not isinstance(jr, dict):
            raise RobotFileError(f"{where}: each joint must be a mapping, got {type(jr).__name__}")
        jname = jr.get("name")
        if not isinstance(jname, str) or not jname:
            raise RobotFileError(f"{where}: missing or empty 'name'")
        where = f"{self.where}: joint {jname!r}"
        jtype = jr.get("type", "revolute")
        if jtype not in JOINT_TYPES:
            raise RobotFileError(f"{where}: type {jtype!r} is not one of {JOINT_TYPES}")

        geom = set(_DH_KEYS.get(self.conv, ("origin", "axis", "after") if self.conv == "urdf" else ("axis", "link")))
        unknown = set(jr) - geom - _COMMON_JOINT_KEYS
        if unknown:
            raise RobotFileError(f"{where}: unknown key(s) {sorted(unknown)} for convention "
                                 f"{self.conv}; allowed: {sorted(geom | _COMMON_JOINT_KEYS)}")
        parent_name = jr.get("parent")
        if parent_name is None:
            parent = i - 1
        elif parent_name == "base":
            parent = -1
        elif parent_name in names:
            parent = names[parent_name]
        else:
            raise RobotFileError(f"{where}: parent {parent_name!r} is not an earlier joint")

        if self.conv == "axis_angle":
            for key in ("axis", "link"):
                if key not in jr:
                    raise RobotFileError(f"{where}: missing key {key!r} (convention axis_angle)")
            axis = self.axis(where, jr["axis"])
            link = self.vector(where, jr["link"], "link")
            pre, post = (), (Op.trans(link),)
            axis = Op.rot(axis, 0.0)  # carries the exact axis
            offset_raw = jr.get("offset", 0)
        elif self.conv == "urdf":
            if "axis" not in jr:
                raise RobotFileError(f"{where}: missing key 'axis' (convention urdf)")
            pre = self.fixed(jr.get("origin", []), f"joint {jname!r} origin")
            post = self.fixed(jr.get("after", []), f"joint {jname!r} after")
            axis = Op.rot(self.axis(where, jr["axis"]), 0.0)
            offset_raw = jr.get("offset", 0)
        else:
            pre, axis, post, offset_raw = self._dh(where, jr, jtype)

        offset = (self.angle(where, offset_raw, "offset") if jtype == "revolute"
                  else self.length(where, offset_raw, "offset"))
        limits = self._limits(where, jr.get("limits"), jtype)
        mimic = jr.get("mimic")
        if isinstance(axis, Op):
            axis_numbers, axis = axis.numbers[0], axis.axis
        else:
            axis_numbers, axis = tuple(axis), np.asarray(axis, dtype=float)
        return Joint(name=jname, type=jtype, parent=parent, axis=axis, pre=pre, post=post,
                     offset=offset, limits=limits, variable=-1 if mimic else nvar,
                     params={k: v for k, v in jr.items() if k != "name"}, axis_numbers=axis_numbers)

    def _dh(self, where, jr, jtype):
        keys = _DH_KEYS[self.conv]
        dkey = "s" if self.conv == "kunze" else "d"
        for key in keys:
            variable = (key == "theta" and jtype == "revolute") or (key == dkey and jtype == "prismatic")
            if key not in jr and not variable:
                raise RobotFileError(f"{where}: missing key {key!r} (convention {self.conv})")
        var_key = "theta" if jtype == "revolute" else dkey
        if var_key in jr and "offset" in jr:
            raise RobotFileError(f"{where}: give the constant part of the joint variable as either "
                                 f"{var_key!r} or 'offset', not both")
        theta = self.angle(where, jr.get("theta", 0), "theta")
        d = self.length(where, jr.get(dkey, 0), dkey)
        a = self.length(where, jr["a"], "a")
        alpha = self.angle(where, jr["alpha"], "alpha")
        offset_raw = jr.get("offset", jr.get(var_key, 0))
        if jtype == "revolute":
            motion_pre, motion_post = (), (Op.trans([0, 0, d]),)
        else:
            motion_pre, motion_post = ((Op.rot(EZ, theta),) if theta else ()), ()
        link = (Op.trans([a, 0, 0]), Op.rot(EX, alpha))
        if self.conv == "modified_dh":
            pre = link + motion_pre
            post = motion_post
        else:
            pre = motion_pre
            post = motion_post + link
        return pre, (0, 0, 1), post, offset_raw

    def _limits(self, where, raw, jtype):
        if raw is None:
            return None
        if not isinstance(raw, (list, tuple)) or len(raw) != 2:
            raise RobotFileError(f"{where}: limits must be [lower, upper], got {raw!r}")
        if jtype == "revolute":
            lo, hi = (self.angle(where, x, "limits", limit=MAX_LIMIT_RAD) for x in raw)
        else:
            lo, hi = (self.length(where, x, "limits") for x in raw)
        if not lo < hi:
            raise RobotFileError(f"{where}: limits lower {lo:g} must be below upper {hi:g}")
        return (lo, hi)

    def resolve_mimic(self, j: Joint, names, joints) -> Joint:
        m = j.params.get("mimic")
        if m is None:
            return j
        where = f"{self.where}: joint {j.name!r}"
        if not isinstance(m, dict) or "joint" not in m or set(m) - {"joint", "multiplier", "offset"}:
            raise RobotFileError(f"{where}: mimic must be a mapping {{joint, multiplier, offset}}")
        src = m["joint"]
        if src not in names or joints[names[src]].is_mimic:
            raise RobotFileError(f"{where}: mimic.joint {src!r} is not an independent joint")
        mult = _Expr(where, {}, False)(m.get("multiplier", 1), "mimic.multiplier")
        moff = (self.angle(where, m.get("offset", 0), "mimic.offset") if j.type == "revolute"
                else self.length(where, m.get("offset", 0), "mimic.offset"))
        return Joint(**{**j.__dict__, "variable": joints[names[src]].variable,
                        "multiplier": mult, "mimic_offset": moff})

    # -- fixed transforms (tool, ends) ----------------------------------------
    def fixed(self, raw, what) -> tuple[Op, ...]:
        """The operations of a fixed transform {translation, rotation} (translation first), or of
        a list of them applied in order."""
        if isinstance(raw, (list, tuple)):
            return tuple(op for k, r in enumerate(raw) for op in self.fixed(r, f"{what}[{k}]"))
        where = f"{self.where}: {what}"
        if not isinstance(raw, dict) or set(raw) - {"translation", "rotation"}:
            raise RobotFileError(f"{where}: must be a mapping with 'translation' and/or 'rotation'")
        ops: list[Op] = []
        if "translation" in raw:
            ops.append(Op.trans(self.vector(where, raw["translation"], "translation")))
        rot = raw.get("rotation")
        if rot is not None:
            ops.extend(self._rotation(where, rot))
        return tuple(ops)

    def _rotation(self, where, rot) -> list[Op]:
        if not isinstance(rot, dict) or len(set(rot) & {"quaternion", "rpy", "axis"}) != 1:
            raise RobotFileError(f"{where}: rotation must give exactly one of "
                                 "quaternion [w,x,y,z], rpy [roll,pitch,yaw], or axis + angle")
        if "quaternion" in rot:
            q = rot["quaternion"]
            if not isinstance(q, (list, tuple)) or len(q) != 4:
                raise RobotFileError(f"{where}: rotation.quaternion must be [w, x, y, z]")
            q = np.array([_Expr(where, {}, False)(x, "quaternion") for x in q])
            n = float(np.linalg.norm(q))
            if abs(n - 1.0) > 1e-4:
                raise RobotFileError(f"{where}: rotation.quaternion has norm {n:.6g}; give a unit quaternion")
            q = q / n
            if q[0] < 0:
                q = -q
            vn = float(np.linalg.norm(q[1:]))
            if vn == 0.0:
                return []
            angle = 2.0 * math.atan2(vn, q[0])
            return [Op.rot(q[1:] / vn, Num(angle, ("turn", angle)))]
        if "rpy" in rot:
            r = rot["rpy"]
            if not isinstance(r, (list, tuple)) or len(r) != 3:
                raise RobotFileError(f"{where}: rotation.rpy must be [roll, pitch, yaw]")
            roll, pitch, yaw = (self.angle(where, x, "rpy") for x in r)
            # R = Rz(yaw) Ry(pitch) Rx(roll) (URDF / ROS convention)
            return [Op.rot(EZ, yaw), Op.rot(EY, pitch), Op.rot(EX, roll)]
        axis = self.axis(where, rot["axis"], "rotation.axis")
        if "angle" not in rot:
            raise RobotFileError(f"{where}: rotation.axis needs rotation.angle")
        return [Op.rot(axis, self.angle(where, rot["angle"], "rotation.angle"))]
