"""The industrial 6R arms of the library (OPW class: axis 1 perpendicular to axis 2, axes 2 and 3
parallel, a spherical wrist): each file loads exactly, is classified OPW, puts its flange where its
source does, and agrees with the independent OPW forward kinematics of py-opw-kinematics
(rs-opw-kinematics, after Brandstoetter, Angerer, Hofbaur 2014) with the OPW parameters of its
source.

Every expected number below is a literal taken from the source named next to it (the ROS-Industrial
URDF joint origins summed by hand, a published OPW parameter set, a data table), not computed with
dq-derive.
"""

import math

import numpy as np
import pytest

import derive
from derive import reference

DEG = math.pi / 180

# Rotation of the end frame at the zero pose, columns = its x, y, z axes in the base frame.
R_ABB_KUKA = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]   # URDF tool0 = link_6 * Ry(90 deg): z = +x, x = -z
R_FANUC = [[0, 0, 1], [0, -1, 0], [1, 0, 0]]      # URDF tool0 = link_6 * rpy(180, -90, 0) deg: z = +x, x = +z
R_ID = np.eye(3).tolist()

# name: (end frame, flange position at the zero pose [m], its rotation, wrist centre at zero [m],
#        joint limits [deg]); the sources are in each file's header.
ZERO = {
    # abb_experimental irb120_3_58_macro.xacro: (0.302 + 0.072, 0, 0.29 + 0.27 + 0.07)
    "irb120": ("tool", [0.374, 0, 0.630], R_ABB_KUKA, [0.302, 0, 0.630],
               [[-165, 165], [-110, 110], [-110, 70], [-160, 160], [-120, 120], [-400, 400]]),
    # abb_experimental irb6700_200_260_macro.xacro: (0.32 + 1.1425 + 0.2, 0, 0.78 + 1.125 + 0.2)
    "irb6700": ("tool", [1.6625, 0, 2.105], R_ABB_KUKA, [1.4625, 0, 2.105],
                [[-170, 170], [-65, 85], [-180, 70], [-300, 300], [-130, 130], [-360, 360]]),
    # abb_experimental PR #137 irb1600_10_145_macro.xacro: (0.15 + 0.3 + 0.3 + 0.065, 0, 0.4865 + 0.7)
    "abb-irb1600": ("tool", [0.815, 0, 1.1865], R_ABB_KUKA, [0.75, 0, 1.1865],
                    [[-180, 180], [-90, 120], [-245, 65], [-200, 200], [-115, 115], [-400, 400]]),
    # kuka_experimental kr6r900_2_macro.xacro: (0.025 + 0.455 + 0.420 + 0.090, 0, 0.400 + 0.025)
    "kr6-r900": ("tool", [0.990, 0, 0.425], R_ABB_KUKA, [0.900, 0, 0.425],
                 [[-170, 170], [-190, 45], [-120, 156], [-185, 185], [-120, 120], [-350, 350]]),
    # kuka_experimental PR #158 kr210r2700extra_macro.xacro: (0.35 + 1.15 + 1.2 + 0.215, 0, 0.675 - 0.041)
    "kr210-r2700": ("tool", [2.915, 0, 0.634], R_ABB_KUKA, [2.700, 0, 0.634],
                    [[-185, 185], [-140, -5], [-120, 155], [-350, 350], [-125, 125], [-350, 350]]),
    # fanuc lrmate200id_macro.xacro: (0.050 + 0.335 + 0.080, 0, 0.330 + 0.330 + 0.035)
    "lrmate200id": ("tool", [0.465, 0, 0.695], R_FANUC, [0.385, 0, 0.695],
                    [[-170, 170], [-100, 145], [-70, 205], [-190, 190], [-125, 125], [-360, 360]]),
    # fanuc m710ic50_macro.xacro: (0.150 + 1.016 + 0.175, 0, 0.565 + 0.870 + 0.170); limits in rad there
    "m710ic": ("tool", [1.341, 0, 1.605], R_FANUC, [1.166, 0, 1.605],
               np.degrees([[-3.1415, 3.1415], [-1.5707, 2.3561], [-2.7925, 4.8869], [-6.2830, 6.2830],
                           [-2.1816, 2.1816], [-6.2831, 6.2831]]).tolist()),
    # motoman PR #493 gp8_macro.xacro: (0.040 + 0.340 + 0.080, 0, 0.330 + 0.345 + 0.040); limits in rad there
    "gp8": ("tool", [0.460, 0, 0.715], R_FANUC, [0.380, 0, 0.715],
            np.degrees([[-2.9670, 2.9670], [-1.1344, 2.5307], [-1.2217, 3.3161], [-3.3161, 3.3161],
                        [-2.3561, 2.3561], [-6.2831, 6.2831]]).tolist()),
    # staubli_experimental tx2_60_macro.xacro: (0, 0.02, 0.375 + 0.29 + 0.31 + 0.07), tool0 = link_6
    "tx2-60": ("flange", [0, 0.02, 1.045], R_ID, [0, 0.02, 0.975],
               [[-180, 180], [-127.5, 127.5], [-152.5, 152.5], [-270, 270], [-121, 132.5], [-270, 270]]),
    # staubli rx160_macro.xacro: (0.15, 0, 0.55 + 0.825 + 0.625 + 0.11), tool0 = link_6
    "rx160": ("flange", [0.15, 0, 2.11], R_ID, [0.15, 0, 2.0],
              [[-160, 160], [-137.5, 137.5], [-150, 150], [-270, 270], [-105, 120], [-270, 270]]),
    # DENSORobot/denso_robot_ros vs060.urdf: (-0.010, 0, 0.1815 + 0.1635 + 0.305 + 0.1645 + 0.1355 + 0.070)
    "vs060": ("flange", [-0.010, 0, 1.020], R_ID, [-0.010, 0, 0.950],
              np.degrees([[-2.96706, 2.96706], [-2.094395, 2.094395], [-2.181662, 2.70526],
                          [-4.712389, 4.712389], [-2.094395, 2.094395], [-6.283185, 6.283185]]).tolist()),
    # Kawasaki-Robotics/khi_robot rs007n_macro.xacro: (0, 0, 0.36 + 0.355 + 0.0925 + 0.2825 + 0.078), link6
    "rs007n": ("flange", [0, 0, 1.168], R_ID, [0, 0, 1.09],
               [[-180, 180], [-135, 135], [-155, 155], [-200, 200], [-125, 125], [-360, 360]]),
    # Corke's mdl_puma560 at qz: T = [I, (a2 + a3, -d3, d4)], the book's p560.fkine(qz)
    "puma560": ("flange", [0.4521, -0.15005, 0.4318], R_ID, [0.4521, -0.15005, 0.4318],
                [[-160, 160], [-45, 225], [-225, 45], [-110, 170], [-100, 100], [-266, 266]]),
}
NAMES = sorted(ZERO)

# Published OPW parameter sets (a1, a2, b, c1, c2, c3, c4, offsets [deg], sign corrections), in the
# convention of opw_kinematics / rs-opw-kinematics: OPW angle = sign * q - offset.
OPW_PUBLISHED = {
    # abb_experimental PR #137 config/opw_parameters_irb1600_10_145.yaml (also rs-opw-kinematics abb_1600)
    "abb-irb1600": (0.150, 0.0, 0.0, 0.4865, 0.700, 0.600, 0.065, (0, 0, -90, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
    # kuka_experimental melodic-devel config/opw_parameters_kr6r900_2.yaml
    "kr6-r900": (0.025, -0.025, 0.0, 0.400, 0.455, 0.420, 0.090, (0, -90, 0, 0, 0, 0), (-1, 1, 1, -1, 1, -1)),
    # motoman PR #493 config/opw_parameters_gp8.yaml
    "gp8": (0.040, -0.040, 0.0, 0.330, 0.345, 0.340, 0.080, (0, 0, -90, 0, 0, 180), (1, 1, -1, -1, -1, -1)),
    # staubli_experimental kinetic-devel config/opw_parameters_tx2_60.yaml
    "tx2-60": (0.0, 0.0, 0.02, 0.375, 0.29, 0.31, 0.07, (0, 0, 0, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
    # rs-opw-kinematics src/parameters_robots.rs, Parameters::staubli_rx160
    "rx160": (0.15, 0.0, 0.0, 0.55, 0.825, 0.625, 0.11, (0, 0, 0, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
}
# No OPW set is published for these: the parameters are read off the same URDF / DH table as the
# file (lengths as in the source; offsets and signs as in the published sets of the same vendor:
# ABB IRB 2400 of opw_kinematics, FANUC M-16iB/20 of ros-industrial/fanuc, KUKA KR 6 R900-2). The
# comparison still checks the file against an independent FK and its frame conventions.
OPW_FROM_SOURCE = {
    "irb120": (0.0, -0.070, 0.0, 0.290, 0.270, 0.302, 0.072, (0, 0, -90, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
    "irb6700": (0.32, -0.2, 0.0, 0.78, 1.125, 1.1425, 0.2, (0, 0, -90, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
    "kr210-r2700": (0.35, 0.041, 0.0, 0.675, 1.15, 1.2, 0.215, (0, -90, 0, 0, 0, 0), (-1, 1, 1, -1, 1, -1)),
    "lrmate200id": (0.050, -0.035, 0.0, 0.330, 0.330, 0.335, 0.080, (0, 0, -90, 0, 0, 180), (1, 1, -1, -1, -1, -1)),
    "m710ic": (0.150, -0.170, 0.0, 0.565, 0.870, 1.016, 0.175, (0, 0, -90, 0, 0, 180), (1, 1, -1, -1, -1, -1)),
    "vs060": (0.0, -0.010, 0.0, 0.345, 0.305, 0.300, 0.070, (0, 0, 0, 0, 0, 0), (1, 1, 1, 1, 1, 1)),
    "rs007n": (0.0, 0.0, 0.0, 0.36, 0.355, 0.375, 0.078, (0, 0, 0, 0, 0, 0), (-1, 1, -1, 1, -1, 1)),
    # Corke's DH table: b = -d3, a2 = a3 (elbow offset), c2 = a2, c3 = d4, c4 = d6 = 0
    "puma560": (0.0, 0.0203, -0.15005, 0.0, 0.4318, 0.4318, 0.0, (0, -90, 90, 0, 0, 0), (1, -1, -1, 1, -1, 1)),
}
# Constant frame changes, T_file(q) = Rz(base) T_opw(q) Rz(tool) [deg]: only the RS007N needs one,
# its URDF moves the arm in the y-z plane of its base frame (J2, J3, J5 about x at the zero pose).
FRAMES = {"rs007n": (90, -90)}


def _rz(deg):
    c, s = math.cos(deg * DEG), math.sin(deg * DEG)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


def _opw_robot(params):
    opw = pytest.importorskip("py_opw_kinematics")
    a1, a2, b, c1, c2, c3, c4, offsets, signs = params
    model = opw.KinematicModel(a1=a1, a2=a2, b=b, c1=c1, c2=c2, c3=c3, c4=c4,
                               offsets=tuple(float(o) * DEG for o in offsets),
                               flip_axes=tuple(s < 0 for s in signs))
    return opw.Robot(model, degrees=False)


@pytest.mark.parametrize("name", NAMES)
def test_loads_exact_6r(name):
    r = derive.load_robot(name)
    assert r.exact, "every fixed angle is a multiple of pi/12"
    assert r.dof == 6 and [j.type for j in r.joints] == ["revolute"] * 6
    assert r.default_end == ZERO[name][0]
    assert r.source and r.title


@pytest.mark.parametrize("name", NAMES)
def test_limits_are_the_sources(name):
    np.testing.assert_allclose(np.degrees(derive.load_robot(name).limits), ZERO[name][4], atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_classified_opw_with_its_wrist_centre(name):
    c = derive.classify(name)
    assert (c.cls, c.nominal_cls) == ("OPW", "OPW")
    # The VS-060's forearm runs 0.010 m off the J3 axis normal (OPW a2), which is exactly NEAR_TOL:
    # the classifier lists it as a near miss of "axes 3 and 4 intersecting". It is the real geometry.
    assert c.near_misses == (["axes 3 and 4: intersecting within 0.01 m (not within 1e-09)"]
                             if name == "vs060" else [])
    assert c.wrist.axes == (4, 5, 6) and c.wrist.spherical
    np.testing.assert_allclose(c.wrist.point, ZERO[name][3], atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_flange_at_the_zero_pose(name):
    t = reference.fk_matrix(name, np.zeros(6))
    np.testing.assert_allclose(t[:3, 3], ZERO[name][1], atol=1e-12)
    np.testing.assert_allclose(t[:3, :3], ZERO[name][2], atol=1e-12)
    # the dual-quaternion FK agrees
    q = reference.fk(name, np.zeros(6))
    np.testing.assert_allclose(derive.dualquat.to_matrix(q), t, atol=1e-12)


def test_puma560_published_poses():
    # Corke, Robotics, Vision and Control (MATLAB toolbox): p560.fkine(qz) and p560.fkine(qr),
    # printed to 4 decimals: qz -> [I, (0.4521, -0.1500, 0.4318)], qr -> [I, (0.0203, -0.1500, 0.8636)]
    for q_deg, p in [((0, 0, 0, 0, 0, 0), (0.4521, -0.1500, 0.4318)),
                     ((0, 90, -90, 0, 0, 0), (0.0203, -0.1500, 0.8636))]:
        t = reference.fk_matrix("puma560", np.radians(q_deg))
        np.testing.assert_allclose(t[:3, 3], p, atol=6e-5)
        np.testing.assert_allclose(t[:3, :3], np.eye(3), atol=1e-12)


def test_lrmate200id_published_poses():
    # mattj23/lrmate-200id, test_cases/r30ib_forward_kinematics.json (cases 1 and 2): joint values as
    # entered on an R-30iB controller (deg; J3 measured from the horizontal, so the serial J3 of the
    # file is J2 + J3) and the flange pose in FANUC's world frame (mm; 0.330 m above base_link),
    # the 4x4 matrix given column by column.
    cases = [
        ((17.795304119777708, 9.63529729650715, 40.3284447668726, 41.9839869496418,
          50.29966354151829, 53.881649348808025),
         (-0.42918435783060316, 0.7574045048077612, -0.4920764199699502, 0.0,
          -0.9020426820537509, -0.3872015344263884, 0.19077204064308287, 0.0,
          -0.04604114189296839, 0.5257503094005371, 0.8493920328201997, 0.0,
          318.11589386239353, 145.34934793767331, 636.7796296820055, 1.0)),
        ((20.63796843683733, 43.1397243310845, 55.05694273319494, 29.665779715975674,
          13.775742025969212, 2.2083197495325146),
         (-0.9409292785054759, 0.1946798810024597, 0.2770412185650949, 0.0,
          -0.10975124008827693, -0.9493666891328625, 0.29437655284344916, 0.0,
          0.32032289669995495, 0.24658190018282927, 0.914653272203175, 0.0,
          436.2966556321629, 174.39823366682805, 608.6228601543556, 1.0)),
    ]
    for (j1, j2, j3, j4, j5, j6), cols in cases:
        expected = np.array(cols).reshape(4, 4).T
        t = reference.fk_matrix("lrmate200id", np.radians([j1, j2, j2 + j3, j4, j5, j6]))
        np.testing.assert_allclose(t[:3, :3], expected[:3, :3], atol=1e-9)
        np.testing.assert_allclose(t[:3, 3] * 1000 - [0, 0, 330], expected[:3, 3], atol=1e-6)


@pytest.mark.parametrize("name", sorted({**OPW_PUBLISHED, **OPW_FROM_SOURCE}))
def test_fk_equals_py_opw_kinematics(name, rng):
    # Same base and end frame on both sides (the OPW base is the file's base, the OPW flange frame
    # is the file's end frame), except for the RS007N (FRAMES).
    params = OPW_PUBLISHED.get(name) or OPW_FROM_SOURCE[name]
    base, tool = FRAMES.get(name, (0, 0))
    q = rng.uniform(-math.pi, math.pi, size=(100, 6))
    expected = _rz(base) @ _opw_robot(params).batch_forward(q).as_matrix() @ _rz(tool)
    np.testing.assert_allclose(reference.fk_matrix(name, q), expected, atol=1e-12)


def test_kr210_r2700_wrist_centre_equals_the_published_kr270_r2700_set(rng):
    # kuka_experimental PR #259 config/opw_parameters_kr270r2700.yaml: the same KR QUANTEC arm
    # (a1 0.35, a2 0.041, c1 0.675, c2 1.15, c3 1.2) with the KR 270's wrist (c4 0.24). The frames
    # agree but the flange distances differ, so compare the wrist centres: p - c4 * z.
    kr270 = (0.35, 0.041, 0.0, 0.675, 1.15, 1.2, 0.24, (0, -90, 0, 0, 0, 0), (-1, 1, 1, -1, 1, -1))
    q = rng.uniform(-math.pi, math.pi, size=(100, 6))
    t_opw = _opw_robot(kr270).batch_forward(q).as_matrix()
    t = reference.fk_matrix("kr210-r2700", q)
    wc_opw = t_opw[:, :3, 3] - 0.24 * t_opw[:, :3, 2]
    wc = t[:, :3, 3] - 0.215 * t[:, :3, 2]
    np.testing.assert_allclose(wc, wc_opw, atol=1e-12)
    np.testing.assert_allclose(t[:, :3, :3], t_opw[:, :3, :3], atol=1e-12)
