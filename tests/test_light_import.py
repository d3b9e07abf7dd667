"""The light import (issue 32, item 5): loading a library robot and its shipped kernels imports
neither sympy, CasADi, jinja2, yourdfpy nor lxml, and deciding a robot's exactness from its
numbers (derive.model.robot.is_exact) agrees with the exact values sympy builds on demand
(derive.model.exact). Speed is measured, not asserted (docs/architecture.md, "Light import")."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
import yaml

import derive
from derive.model import exact
from derive.model.robot import is_exact, list_robots, robot_from_dict

HEAVY = ("sympy", "casadi", "jinja2", "yourdfpy", "lxml", "dask", "distributed", "zarr", "matplotlib")
LIBRARY = Path(derive.__file__).resolve().parent / "robots"

_LOAD = r"""
import json, sys
import numpy as np
import derive
out = {}
for backend in ("c", "numpy", "python"):
    k = derive.kernels("ur5", backend)
    q = np.array([0.3, -1.1, 1.2, -0.4, 0.8, 0.2])
    sols, n = k.ik(k.fk(q))
    out[backend] = [int(np.ravel(n)[0]), float(np.min(np.abs(np.asarray(sols).reshape(-1, 6) - q).max(axis=1)))]
iiwa = derive.load_robot("iiwa14")
out["iiwa14"] = [iiwa.dof, iiwa.exact]
out["loaded"] = sorted(m for m in %r if m in sys.modules)
print(json.dumps(out))
"""


def test_loading_shipped_kernels_imports_no_heavy_module():
    # the first use of a C kernel builds its CPython extension, which renders a template (jinja2,
    # docs/architecture.md "Light import"): build it in a process of its own, so that the check
    # below loads built kernels also where the user cache is empty (this test run alone)
    warm = subprocess.run([sys.executable, "-c", "import derive; derive.kernels('ur5', 'c')"],
                          capture_output=True, text=True, timeout=300)
    assert warm.returncode == 0, warm.stderr
    run = subprocess.run([sys.executable, "-c", _LOAD % (HEAVY,)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.strip().splitlines()[-1])
    for backend in ("c", "numpy", "python"):
        n, err = out[backend]
        assert n == 8 and err < 1e-9, (backend, n, err)     # the kernels work, not just load
    assert out["iiwa14"] == [7, True]
    assert out["loaded"] == []


def test_heavy_public_names_still_resolve():
    from derive import refine                       # PEP 562: imported on first use
    from derive.refinement.solver import refine as solver_refine
    assert refine is solver_refine and derive.refine is solver_refine
    with pytest.raises(AttributeError):
        derive.no_such_name
    assert derive.model.urdf.urdf_description is not None       # the URDF reader on first use
    assert callable(derive.codegen.emit.render_kernels)


def _symbolic_exactness(robot) -> bool:
    """The exactness as it was decided before the light import: every fixed angle's exact
    value (sympy) a multiple of pi/12."""
    ops = [op for j in robot.joints for op in (*j.pre, *j.post)]
    ops += [op for e in robot.ends.values() for op in e.ops]
    angles = [exact.op_form(op)[1] for op in ops if op.kind == "R"]
    angles += [exact.value(j.offset) for j in robot.joints if j.type == "revolute"]
    return all(exact.multiple_of_pi_12(a) for a in angles)


@pytest.mark.parametrize("name", list_robots())
def test_numeric_exactness_agrees_with_the_exact_values(name):
    robot = derive.load_robot(name)
    assert robot.exact == _symbolic_exactness(robot)


def _ur5(**changes) -> dict:
    data = yaml.safe_load((LIBRARY / "ur5.yaml").read_text())
    data.update(changes)
    return data


def _degrees():
    data = _ur5(units={"length": "m", "angle": "deg"})
    for j in data["joints"]:
        j["limits"] = [-360, 360]
    return data


def _alphas(data, value):
    for j in data["joints"]:
        if str(j["alpha"]) in ("pi/2", "-pi/2"):
            negative = str(j["alpha"]).startswith("-")
            j["alpha"] = (f"-({value})" if isinstance(value, str) else -value) if negative else value
    return data


def _tool(rotation):
    return _ur5(tool={"translation": [0, 0, 0.1], "rotation": rotation})


@pytest.mark.parametrize("data, expected", [
    (_alphas(_ur5(), 1.5707963267948966), True),            # pi/2 as printed
    (_alphas(_ur5(), 1.5707963267948966 + 1e-13), True),    # within SNAP_TOL: snapped
    (_alphas(_ur5(), 1.5707963267948966 + 5e-12), False),   # beyond: a float
    (_alphas(_ur5(), 1.5708), False),
    (_alphas(_ur5(), "pi/7 + pi/2 - pi/7"), True),
    (_alphas(_ur5(), "pi/2 + pi/100"), False),
    (_alphas(_degrees(), 90), True),
    (_alphas(_degrees(), 90.0000001), False),
    (_tool({"quaternion": [math.cos(math.pi / 8), 0, 0, math.sin(math.pi / 8)]}), True),   # 45 deg
    (_tool({"quaternion": [math.cos(0.1), 0, math.sin(0.1), 0]}), False),
    (_tool({"rpy": [0, "pi/12", "-pi/4"]}), True),
    (_tool({"axis": [0.6, 0.8, 0], "angle": "pi/3"}), True),
    (_tool({"axis": [0.6, 0.8, 0], "angle": 0.3}), False),
])
def test_exactness_of_edited_descriptions(data, expected):
    robot = robot_from_dict(data)
    assert robot.exact is expected
    assert _symbolic_exactness(robot) is expected
    assert is_exact(robot.joints, robot.ends) is expected


def test_exact_values_are_those_of_the_file():
    robot = derive.load_robot("ur5")
    d1 = robot.joints[0].post[0]                    # Tz(d1) of the first DH joint
    assert exact.op_form(d1) == (0, 0, sp.Symbol("d1", real=True))   # a length parameter stays its symbol
    alpha = robot.joints[0].post[-1]
    assert exact.op_form(alpha) == ((1, 0, 0), sp.pi / 2)
    deg = robot_from_dict(_alphas(_degrees(), 90))
    assert exact.op_form(deg.joints[0].post[-1])[1] == sp.pi / 2
    axis = robot_from_dict(_tool({"axis": [0.6, 0.8, 0], "angle": "pi/3"})).ends["tool"].ops[-1]
    assert exact.op_form(axis)[0] == (sp.Rational(3, 5), sp.Rational(4, 5), 0)
    assert np.allclose(axis.axis, [0.6, 0.8, 0])


_CLI = r"""
import contextlib, io, json, sys
import derive.cli
out = {"import": sorted(m for m in %r if m in sys.modules)}
for name, argv in (("classify", ["classify", "ur5", "--json"]),
                   ("fk", ["fk", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--json"])):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = derive.cli.main(argv)
    out[name] = [rc, json.loads(buf.getvalue())]
out["loaded"] = sorted(m for m in %r if m in sys.modules)
print(json.dumps(out))
"""


def test_command_line_imports_no_heavy_module_for_classify_and_fk():
    """``import derive.cli`` and ``dq-derive classify ur5`` / ``fk`` import none of the heavy
    modules: the emitters, reports, refine, export, plot and bench import them inside their
    subcommands (issue 30: classify of a URDF within 2 s from the command line)."""
    run = subprocess.run([sys.executable, "-c", _CLI % (HEAVY, HEAVY)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["import"] == []
    rc, c = out["classify"]
    assert rc == 0 and c["robot"] == "ur5" and c["n"] == 6
    assert c["class"] == "UR"                       # axes 2, 3, 4 parallel (alpha2 = alpha3 = 0 in the DH table)
    rc, fk = out["fk"]
    # UR5 DH at q = 0 (Universal Robots' table): x = a2 + a3 = -(0.425 + 0.39225), y = -(d4 + d6), z = d1 - d5
    assert rc == 0
    assert np.allclose(fk["position"]["value"], [-(0.425 + 0.39225), -(0.10915 + 0.0823), 0.089159 - 0.09465],
                       atol=1e-9)
    assert out["loaded"] == []
