"""Motion-capture files as labs write them: a C3D's own axes (POINT:X_SCREEN/Y_SCREEN),
``Subject:`` label prefixes, and the Plug-in Gait lower-body set, down to a synthetic
Plug-in Gait C3D read back and fitted to the pose that made it."""

import importlib.util
import itertools
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody._body import rest_geometry
from diffbody._joint_angles import joint_angles
from diffbody.clouds._cloud_fit import FitStatus
from diffbody.files._data_files import data_file
from diffbody.files._marker_files import c3d_screen_axes, read_c3d, read_markers
from diffbody.files._marker_trial import LAB_AXES, MarkerFileError
from diffbody.files._markerset_file import load_markerset
from diffbody.files._trc import read_trc
from diffbody.mocap._marker_layout import mocap_layout
from diffbody.mocap._markerset import world_markers
from diffbody.mocap._motion_fit import fit_motion
from diffbody.problem._problem import make_problem

ezc3d = pytest.importorskip("ezc3d")

STATIC = data_file("mocap/subject01_static.trc")
PIG = (
    ("LASI", "RASI", "LPSI", "RPSI")
    + tuple(f"L{m}" for m in ("THI", "KNE", "TIB", "ANK", "HEE", "TOE"))
    + tuple(f"R{m}" for m in ("THI", "KNE", "TIB", "ANK", "HEE", "TOE"))
)


def write_c3d(path, names, lab_mm, rate=100.0, screen=None):
    """A C3D of marker positions in the lab frame: lab_mm (n_frames, n_markers, 3) in mm,
    NaN where unseen; screen: (X_SCREEN, Y_SCREEN) parameters, or None to write none."""
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    if screen is not None:
        c3d.add_parameter("POINT", "X_SCREEN", [screen[0]])
        c3d.add_parameter("POINT", "Y_SCREEN", [screen[1]])
    points = np.ones((4, len(names), len(lab_mm)))
    points[:3] = np.transpose(lab_mm, (2, 1, 0))
    c3d["data"]["points"] = points
    c3d.write(str(path))
    return path


# --- the lab's axes ------------------------------------------------------------------------------
SIGNED = [f"{s}{a}" for a in "XYZ" for s in "+-"]


@pytest.mark.parametrize(
    "x_screen, y_screen", [(x, y) for x, y in itertools.product(SIGNED, SIGNED) if x[1] != y[1]]
)
def test_screen_axes_are_rotations_that_put_the_screen_up_up(x_screen, y_screen):
    """Every valid pair gives a proper rotation taking the screen's up axis to world +Z
    and its right axis to world +X (forward)."""
    R = c3d_screen_axes(x_screen, y_screen)
    axis = {
        f"{s}{a}": (1 if s == "+" else -1) * np.eye(3)[i] for s in "+-" for i, a in enumerate("XYZ")
    }
    np.testing.assert_array_equal(R @ R.T, np.eye(3))
    assert np.linalg.det(R) == 1.0
    np.testing.assert_array_equal(R @ axis[y_screen], [0, 0, 1])
    np.testing.assert_array_equal(R @ axis[x_screen], [1, 0, 0])


def test_screen_axes_of_the_common_labs():
    """Vicon and Qualisys (+X right, +Z up): the identity, `z-up`; OpenSim's Y up: `opensim`.
    Without X_SCREEN the lab's X is forward; without either the lab is Z up."""
    np.testing.assert_array_equal(c3d_screen_axes("+X", "+Z"), LAB_AXES["z-up"])
    np.testing.assert_array_equal(c3d_screen_axes("+X", "+Y"), LAB_AXES["opensim"])
    np.testing.assert_array_equal(c3d_screen_axes(None, "+Y"), LAB_AXES["opensim"])
    np.testing.assert_array_equal(c3d_screen_axes(None, None), LAB_AXES["z-up"])
    np.testing.assert_array_equal(c3d_screen_axes(" x ", "z"), LAB_AXES["z-up"])  # unsigned
    np.testing.assert_array_equal(c3d_screen_axes(None, "+X") @ [0, 1, 0], [1, 0, 0])
    with pytest.raises(MarkerFileError, match=r"lab.c3d: parameters POINT:X_SCREEN.*same lab axis"):
        c3d_screen_axes("-Z", "+Z", "lab.c3d")
    with pytest.raises(MarkerFileError, match=r"POINT:Y_SCREEN: expected a signed lab axis.*'up'"):
        c3d_screen_axes("+X", "up", "lab.c3d")


@pytest.fixture(scope="module")
def static_frames():
    """Three frames of the shipped OpenSim static trial (Y up), in the world and in mm in
    its lab frame."""
    trial = read_trc(STATIC)
    world = trial.positions[:3]
    lab_mm = 1000 * world @ LAB_AXES["opensim"]  # R.T p: world -> lab
    return trial.names, world, lab_mm


def test_c3d_with_y_up_screen_reads_like_the_trc(tmp_path, static_frames):
    """A C3D of the OpenSim trial with Y_SCREEN +Y reads, by default, as read_trc reads the
    TRC (OpenSim's axes), to C3D's float32."""
    names, world, lab_mm = static_frames
    path = write_c3d(tmp_path / "yup.c3d", names, lab_mm, screen=("+X", "+Y"))
    trial = read_markers(path)
    assert trial.names == names
    np.testing.assert_allclose(trial.positions, world, rtol=0, atol=1e-7)
    z_up = read_markers(path, axes="z-up")  # an explicit axes wins over the file's
    np.testing.assert_allclose(z_up.positions, lab_mm / 1000, rtol=0, atol=1e-7)


def test_c3d_without_screen_is_z_up(tmp_path, static_frames):
    names, _, lab_mm = static_frames
    path = write_c3d(tmp_path / "plain.c3d", names, lab_mm)
    np.testing.assert_allclose(read_c3d(path).positions, lab_mm / 1000, rtol=0, atol=1e-7)
    turned = read_c3d(path, axes="opensim")
    np.testing.assert_allclose(
        turned.positions, lab_mm[..., [0, 2, 1]] * [1, -1, 1] / 1000, rtol=0, atol=1e-7
    )


def test_bad_screen_parameter_names_the_file(tmp_path, static_frames):
    names, _, lab_mm = static_frames
    path = write_c3d(tmp_path / "bad.c3d", names, lab_mm, screen=("+Y", "+Y"))
    with pytest.raises(MarkerFileError, match=rf"^{path}: parameters POINT:X_SCREEN"):
        read_c3d(path)
    assert read_c3d(path, axes="z-up").n_markers == len(names)


# --- subject prefixes ----------------------------------------------------------------------------
def _trc_text(names):
    head = [
        "PathFileType\t4\t(X/Y/Z)\tt.trc",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits",
        f"100\t100\t1\t{len(names)}\tmm",
        "Frame#\tTime\t" + "".join(f"{n}\t\t\t" for n in names),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, len(names) + 1)),
        "",
        "1\t0\t" + "\t".join(str(v) for v in range(1, 3 * len(names) + 1)),
    ]
    return "\n".join(head) + "\n"


@pytest.mark.parametrize("kind", ["c3d", "trc"])
def test_subject_prefixes_are_stripped(tmp_path, kind):
    labels = ("Subject01:LASI", "Subject01:RASI", "C7", "Lab:Subject01:LPSI")
    path = tmp_path / f"t.{kind}"
    if kind == "c3d":
        write_c3d(path, labels, np.arange(12.0).reshape(1, 4, 3) + 1)
    else:
        path.write_text(_trc_text(labels))
    assert read_markers(path).names == ("LASI", "RASI", "C7", "LPSI")
    kept = read_markers(path, strip_prefix=False)
    assert kept.names == labels
    np.testing.assert_array_equal(kept.positions, read_markers(path).positions)


@pytest.mark.parametrize("kind", ["c3d", "trc"])
def test_two_subjects_collide(tmp_path, kind):
    """Two subjects' markers become one name once stripped: an error naming the file, the
    labels and the option that keeps them apart; that option reads the file."""
    labels = ("Anna:LASI", "Anna:RASI", "Ben:LASI")
    path = tmp_path / f"two.{kind}"
    if kind == "c3d":
        write_c3d(path, labels, np.arange(9.0).reshape(1, 3, 3) + 1)
    else:
        path.write_text(_trc_text(labels))
    with pytest.raises(MarkerFileError) as err:
        read_markers(path)
    message = str(err.value)
    where = "parameter POINT:LABELS" if kind == "c3d" else "line 4"
    assert message.startswith(f"{path}: {where}: ")
    assert "'Anna:LASI' and 'Ben:LASI' are both 'LASI'" in message
    assert "strip_prefix=False" in message
    assert read_markers(path, strip_prefix=False).names == labels


def test_c3d_label_given_twice(tmp_path):
    path = write_c3d(tmp_path / "twice.c3d", ("A", "A"), np.ones((1, 2, 3)))
    with pytest.raises(MarkerFileError, match=r"POINT:LABELS: marker names given twice: A"):
        read_c3d(path, strip_prefix=False)


# --- the Plug-in Gait set ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pig(male50):
    return load_markerset("plugin-gait-lower", male50)


def _script():
    path = data_file("markersets/make_plugin_gait_lower.py")
    spec = importlib.util.spec_from_file_location("make_plugin_gait_lower", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_plugin_gait_set_is_what_its_script_writes(male50, pig, tmp_path, capsys):
    """The shipped file is the script's output for the default body (its placements are
    derived, not typed), and loads by name with its 16 markers in Plug-in Gait's order."""
    script = _script()
    script.write(script.build(male50), tmp_path / "pig.json")
    shipped = data_file("markersets/plugin-gait-lower.json")
    assert json.loads(shipped.read_text()) == json.loads((tmp_path / "pig.json").read_text())
    assert shipped.read_text() == (tmp_path / "pig.json").read_text()
    assert pig.names == PIG
    kinds = dict(zip(pig.names, pig.kinds))
    assert {n for n, k in kinds.items() if k == "tracking"} == {"LTHI", "RTHI", "LTIB", "RTIB"}


def test_plugin_gait_set_sits_on_the_landmarks(male50, female50):
    """Standard position, both default bodies: every marker outside every sphere and within
    2 cm of the skin; left markers left; the knee and ankle markers lateral of their joints
    at the joints' heights, the thigh and tibia markers in the lower third and in the plane
    of the joints and the lateral marker (Plug-in Gait's rule for the flexion axes); the heel
    at the toe marker's height; the ASIS 0.26 m apart (Davis's model on male50)."""
    for body in (male50, female50):
        markers = load_markerset("plugin-gait-lower", body)
        joints, centers = rest_geometry(body)
        seg = np.asarray(markers.segments)
        R = np.asarray(body.R_socket_rest)[seg]
        p = joints[np.asarray(body.proximal_joint)[seg]]
        p = dict(zip(markers.names, p + np.einsum("kij,kj->ki", R, np.asarray(markers.offsets))))
        radii = np.asarray(body.sphere_radii)
        for name, q in p.items():
            clearance = np.min(np.linalg.norm(centers - q, axis=1) - radii)
            assert 0.002 < clearance < 0.02, (body.name, name, clearance)
            assert (q[1] > 0) == (name[0] == "L"), name
        for side, s in (("L", 1), ("R", -1)):
            sd = "left" if s > 0 else "right"
            hip, knee, ankle = (
                joints[body.joint_index(f"{sd}_{j}")] for j in ("hip", "knee", "ankle")
            )
            for marker, joint in (("KNE", knee), ("ANK", ankle)):
                d = p[side + marker] - joint
                assert s * d[1] > 0.03 and abs(d[0]) < 1e-9 and abs(d[2]) < 1e-9, (side, marker)
            for marker, top, bottom in (("THI", hip, knee), ("TIB", knee, ankle)):
                q = p[side + marker]
                assert bottom[2] < q[2] < top[2] - 2 / 3 * (top[2] - bottom[2])
                assert abs(q[0] - knee[0]) < 1e-9  # the hip, knee and ankle's x: a frontal plane
            assert abs(p[side + "HEE"][2] - p[side + "TOE"][2]) < 1e-3
            assert p[side + "HEE"][0] < ankle[0] < p[side + "TOE"][0]
        if body is male50:
            assert np.linalg.norm(p["LASI"] - p["RASI"]) == pytest.approx(0.2602, abs=1e-3)


# --- a synthetic Plug-in Gait trial, read and fitted ---------------------------------------------
N_FRAMES = 3
# The lab: Z up, its walkway along +Y (X_SCREEN "+Y"), so that the file's own screen axes,
# not a default, turn it into the world.
SCREEN = ("+Y", "+Z")
LOWER_JOINTS = (
    "center_hip",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
LEG_ANGLES = tuple(
    f"{j}_{s}"
    for j in (
        "hip_flexion",
        "hip_adduction",
        "hip_rotation",
        "knee_flexion",
        "ankle_angle",
    )
    for s in "rl"
)


@pytest.fixture(scope="module")
def pig_trial(male50, pig, tmp_path_factory):
    """The default body posed by known free vectors of the set's own unknowns (every leg
    joint and the placement moved; a few degrees to 10 degrees a frame), its 16 markers
    written as a Vicon-style C3D: lab Z up, mm, ``Subject01:`` labels, the screen axes set."""
    rng = np.random.default_rng(7)
    lay = mocap_layout(male50, pig)
    rest = male50.rest_pose()
    # Compiled (op by op, the set-up's operations are hundreds of programs).
    problem = eqx.filter_jit(make_problem)(male50, lay.pose, rest)
    pose_of = eqx.filter_jit(lambda problem, x: problem.pose(x, rest))
    n = lay.pose.n_free
    x = np.asarray(problem.x0) + 0.15 * rng.standard_normal(n)
    x[-6:] = [0.4, 1.2, 0.0, 0.0, 0.0, 0.3]  # placed in the lab and turned
    step = 0.04 * rng.standard_normal(n)
    step[-6:] = [0.05, 0.0, 0.0, 0.0, 0.0, 0.02]  # walking forward, turning a little
    fk = jax.jit(lambda pose: (world_markers(male50, pose, pig), db.forward(male50, pose)))
    poses = [pose_of(problem, jnp.asarray(x + k * step)) for k in range(N_FRAMES)]
    out = [fk(p) for p in poses]
    world = np.stack([np.asarray(m) for m, _ in out])
    R_world_lab = c3d_screen_axes(*SCREEN)
    lab_mm = 1000 * world @ R_world_lab  # R.T p, per marker
    labels = [f"Subject01:{name}" for name in pig.names]
    path = write_c3d(tmp_path_factory.mktemp("pig") / "walk.c3d", labels, lab_mm, screen=SCREEN)
    joints = np.stack([np.asarray(k.joint_positions) for _, k in out])
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *poses)
    return path, world, joints, stacked


def test_plugin_gait_c3d_recovers_the_pose(male50, pig, pig_trial):
    """Read back with the default axes and prefixes stripped, fitted from the standard
    position. The data are exact but for C3D's float32 (< 1e-7 m at 2 m from the lab's
    origin), and 16 markers fix the lower body: the pelvis (4 markers on a rigid segment),
    each thigh and shank (its proximal joint and two markers). So the hips, knees and ankles
    within 1e-5 m and the hip, knee and ankle flexion and the hip's adduction and rotation
    within 0.01 degrees: the solver's stopping tolerance (1e-4 rad RMS step in float64)
    sets these, not the markers (0.005 degrees and 7e-6 m here; frame 0, solved from
    several starts, 1e-7 m). The foot is the exception: its heel and toe markers lie 4 mm
    below the line through the ankle, so its roll about its long axis (ankle inversion)
    rests on millimetres of lever against the weak pull toward the start (`PULL`): within
    1 degree (0.34 here), and the toe tips, on that axis, within 1e-4 m (2e-5 here)."""
    path, world, joints, truth = pig_trial
    trial = read_markers(path)
    assert trial.names == pig.names
    np.testing.assert_allclose(trial.positions, world, rtol=0, atol=1e-7)
    fit = fit_motion(male50, pig, trial, start=male50.rest_pose())
    assert np.all(fit.status == FitStatus.CONVERGED)
    assert np.max(fit.errors) < 1e-5
    legs = [male50.joint_index(j) for j in LOWER_JOINTS]
    toes = [male50.joint_index(j) for j in ("left_toe_tip", "right_toe_tip")]
    for k in range(N_FRAMES):
        got = np.asarray(db.forward(male50, fit.pose(k)).joint_positions)
        np.testing.assert_allclose(got[legs], joints[k][legs], rtol=0, atol=1e-5)
        np.testing.assert_allclose(got[toes], joints[k][toes], rtol=0, atol=1e-4)
    angles = jax.jit(jax.vmap(lambda pose: joint_angles(male50, pose)))
    fitted, expected = angles(fit.poses), angles(truth)
    for name in LEG_ANGLES:
        np.testing.assert_allclose(fitted[name], expected[name], rtol=0, atol=1e-2, err_msg=name)
    for name in ("ankle_inversion_r", "ankle_inversion_l"):
        np.testing.assert_allclose(fitted[name], expected[name], rtol=0, atol=1.0, err_msg=name)
