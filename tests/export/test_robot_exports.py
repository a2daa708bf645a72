"""What makes the exports usable by a robot: the ball joints' ranges and the URDF hinges'
limits hold every pose the body's limits allow (and the hinges stay away from their
singularity there), MuJoCo's URDF loader reproduces `forward`, the inertia tensors are the
spheres', and the `diffbody export` command writes files MuJoCo loads."""

import json
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from command_line import fails
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import diffbody as db
from diffbody.cli._main import main
from diffbody.export._limit_sets import ROUNDING
from diffbody.export._mjcf import export_mjcf, mujoco_qpos, mujoco_qpos_slices
from diffbody.export._urdf import export_urdf, urdf_joint_values

mujoco = pytest.importorskip("mujoco")

TOL = 1e-9  # m and rotation-matrix entries, as tests/export/test_export.py
AWAY = np.deg2rad(1.0)  # rad, least distance of the URDF middle hinges from +-pi/2


@pytest.fixture(scope="module")
def ball_model(male50, tmp_path_factory):
    return mujoco.MjModel.from_xml_path(
        str(export_mjcf(male50, tmp_path_factory.mktemp("ball") / "male50.xml"))
    )


@pytest.fixture(scope="module")
def urdf_path(male50, tmp_path_factory):
    return export_urdf(male50, tmp_path_factory.mktemp("urdf") / "male50.urdf")


def mujoco_urdf(path):
    """MuJoCo's model of a URDF, its links kept as bodies (no fusing across fixed joints)."""
    robot = ET.parse(path).getroot()
    extension = ET.Element("mujoco")
    ET.SubElement(extension, "compiler", fusestatic="false", discardvisual="true")
    robot.insert(0, extension)
    return mujoco.MjModel.from_xml_string(ET.tostring(robot, encoding="unicode"))


def urdf_limits(path) -> dict[str, tuple[float, float]]:
    robot = ET.parse(path).getroot()
    return {
        j.get("name"): (float(j.find("limit").get("lower")), float(j.find("limit").get("upper")))
        for j in robot.findall("joint")
        if j.get("type") == "revolute"
    }


def pose_within_limits(body, u: np.ndarray) -> db.Pose:
    """The pose whose every segment but the whole body takes the point u (n_seg, 3) of the
    unit cube in its limit set: its swing box (pulled radially into its cone) and twist
    range; the whole body at rest."""
    lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
    w = lo + u[:, :2] * (hi - lo)
    norm = np.linalg.norm(w, axis=-1, keepdims=True)
    cone = np.asarray(body.swing_max)[:, None]
    w = np.where(norm > cone, w * cone / np.maximum(norm, 1e-300), w)
    tau = np.asarray(body.twist_lo) + u[:, 2] * np.asarray(body.twist_hi - body.twist_lo)
    angles = db.angles_from_swing(body, jnp.asarray(w), jnp.asarray(tau))
    rest = body.rest_pose()
    return db.Pose(rest.position, angles.at[0].set(rest.angles[0]))


unit_rows = hnp.arrays(np.float64, (37, 3), elements=st.floats(0.0, 1.0))


@given(u=unit_rows)
def test_limits_hold_every_admissible_pose(male50, ball_model, urdf_path, u):
    """For a pose within the body's limits: each ball's rotation from rest is within its
    range, and each URDF hinge within its limits, the middle ones away from +-pi/2."""
    body = male50
    pose = pose_within_limits(body, u)
    assert bool(jnp.all(db.within_limits(body, pose)))
    q = mujoco_qpos(body, pose)
    for j in range(1, ball_model.njnt):  # the balls (joint 0 is the free joint)
        adr = ball_model.jnt_qposadr[j]
        w, xyz = q[adr], q[adr + 1 : adr + 4]
        angle = 2 * np.arctan2(np.linalg.norm(xyz), w)
        assert ball_model.jnt_limited[j], ball_model.joint(j).name
        assert angle <= ball_model.jnt_range[j, 1] + 1e-12, (ball_model.joint(j).name, angle)
    limits = urdf_limits(urdf_path)
    for name, value in urdf_joint_values(body, pose).items():
        lo, hi = limits[name]
        assert lo <= value <= hi, (name, lo, value, hi)
        if name.endswith("_hinge1"):
            assert abs(value) <= np.pi / 2 - AWAY, (name, value)


def test_ball_ranges_are_honest(male50, ball_model):
    """Ranges are the largest rotation the limits allow: the pelvis links, which cannot move,
    get 0 (and the rounding allowance); the elbow's is at least the largest rotation of its
    limit set's corners (flexion with full pronation) and at most a few degrees beyond."""
    names = [ball_model.joint(j).name for j in range(ball_model.njnt)]
    r = {n: ball_model.jnt_range[j, 1] for j, n in enumerate(names)}
    assert r["left_pelvis_ball"] == ROUNDING and r["pelvis_ball"] == ROUNDING
    i = male50.segment_index("left_forearm")
    flexion, pronation = float(male50.swing_hi[i, 1]), float(male50.twist_hi[i])
    corner = 2 * np.arccos(np.cos(flexion / 2) * np.cos(pronation / 2))
    assert flexion <= corner <= r["left_forearm_ball"] <= corner + np.deg2rad(3)


def test_urdf_in_mujoco_matches_forward(male50, fk_male50, urdf_path):
    """MuJoCo's URDF loader on the export: link frames and origins are `forward`'s twisted
    frames and proximal joints, the standard position included (whole body at rest)."""
    body, model = male50, mujoco_urdf(urdf_path)
    rest = body.rest_pose()
    rng = np.random.default_rng(4)
    poses = [rest]
    for _ in range(6):
        angles = np.stack(
            [rng.uniform(-np.pi, np.pi, 37), rng.uniform(0, np.pi, 37), rng.uniform(-1, 1, 37)], -1
        )
        poses.append(db.Pose(rest.position, jnp.asarray(angles).at[0].set(rest.angles[0])))
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in body.segment_names]
    assert min(bodies) >= 0
    for pose in poses:
        data = mujoco.MjData(model)
        for name, value in urdf_joint_values(body, pose).items():
            data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
        mujoco.mj_kinematics(model, data)
        fk = fk_male50(pose)
        np.testing.assert_allclose(
            data.xpos[bodies],
            np.asarray(fk.joint_positions)[list(body.proximal_joint)],
            rtol=0,
            atol=TOL,
        )
        np.testing.assert_allclose(
            data.xmat[bodies].reshape(-1, 3, 3), np.asarray(fk.R_world_twisted), rtol=0, atol=TOL
        )


def _spheres_inertia(body, segment: str) -> np.ndarray:
    """The inertia tensor (kg m^2) of a segment's spheres about their centre of mass, one
    sphere at a time: solid balls, mass by volume."""
    i = body.segment_index(segment)
    k = body.segment_spheres(segment)
    r = np.asarray(body.sphere_radii)[k]
    o = np.asarray(body.sphere_origins)[k]
    m = float(body.masses[i]) * r**3 / np.sum(r**3)
    c = sum(mk * ok for mk, ok in zip(m, o)) / m.sum()
    total = np.zeros((3, 3))
    for mk, rk, ok in zip(m, r, o):
        d = ok - c
        total += mk * (0.4 * rk**2 * np.eye(3) + np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return total


@pytest.mark.parametrize("segment", ["left_forearm", "head", "right_thigh"])
def test_inertia_is_the_spheres(male50, ball_model, urdf_path, segment):
    """MuJoCo's principal inertia (body_inertia, body_iquat) of the MJCF and of the URDF
    equals the spheres' tensor summed here, at the segment's centroid."""
    expected = _spheres_inertia(male50, segment)
    i = male50.segment_index(segment)
    for model in (ball_model, mujoco_urdf(urdf_path)):
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, segment)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, model.body_iquat[b])
        R = R.reshape(3, 3)
        got = R @ np.diag(model.body_inertia[b]) @ R.T
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(model.body_ipos[b], np.asarray(male50.centroids[i]))
        assert model.body_mass[b] == pytest.approx(float(male50.masses[i]))
    assert not np.allclose(expected, np.eye(3) * np.trace(expected) / 3)  # no one sphere's


# --- the command -------------------------------------------------------------------------
def _arm_pose(body) -> db.Pose:
    u = np.full((37, 3), 0.5)
    return pose_within_limits(body, u)


def test_export_command_mjcf_and_urdf(male50, tmp_path, capsys):
    mjcf, urdf = tmp_path / "body.xml", tmp_path / "body.urdf"
    assert main(["export", "--format", "mjcf", "--out", str(mjcf)]) == 0
    assert main(["export", "--format", "urdf", "--out", str(urdf)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {mjcf}" in out and f"wrote {urdf}" in out
    model = mujoco.MjModel.from_xml_path(str(mjcf))
    assert model.nq == 7 + 4 * (male50.n_segments - 1)
    assert mujoco_urdf(urdf).njnt == 3 * (male50.n_segments - 1)
    assert not (tmp_path / "body.joint_values.json").exists()


def test_export_command_with_pose(male50, tmp_path, capsys):
    pose = _arm_pose(male50)
    pose_file = db.files.save_pose(tmp_path / "pose.json", male50, pose)
    mjcf, urdf = tmp_path / "posed.xml", tmp_path / "posed.urdf"
    loaded = db.files.load_pose(pose_file, male50).pose  # the pose as the file holds it
    argv = ["export", "--pose", str(pose_file), "--out"]
    assert main(argv + [str(mjcf), "--format", "mjcf"]) == 0
    model = mujoco.MjModel.from_xml_path(str(mjcf))
    assert model.key(0).name == "pose" and model.key(1).name == "standard_position"
    np.testing.assert_array_equal(model.key_qpos[0], mujoco_qpos(male50, loaded))
    assert main(argv + [str(urdf), "--format", "urdf"]) == 0
    sidecar = json.loads((tmp_path / "posed.joint_values.json").read_text())
    values = urdf_joint_values(male50, loaded)
    assert sidecar["joint_names"] == list(values) and sidecar["units"] == "rad"
    np.testing.assert_array_equal(sidecar["positions"], [list(values.values())])
    # The command prints the hinge model's warning instead of raising it.
    assert main(argv + [str(mjcf), "--format", "mjcf", "--joints", "hinges"]) == 0
    hinges = mujoco.MjModel.from_xml_path(str(mjcf))
    np.testing.assert_array_equal(hinges.key_qpos[0], mujoco_qpos(male50, loaded, "hinges"))
    assert "warning: export_mjcf(joints='hinges')" in capsys.readouterr().out


def test_export_command_bad_input(tmp_path, capsys):
    out = str(tmp_path / "x.xml")
    assert "invalid choice: 'sdf'" in fails(["export", "--format", "sdf", "--out", out], capsys)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    err = fails(["export", "--format", "mjcf", "--out", out, "--pose", str(bad)], capsys)
    assert str(bad) in err
    missing = tmp_path / "missing.json"
    err = fails(["export", "--format", "mjcf", "--out", out, "--pose", str(missing)], capsys)
    assert str(missing) in err
    err = fails(["export", "--format", "urdf", "--out", out, "--joints", "hinges"], capsys)
    assert "only for --format mjcf" in err


def test_qpos_slices_name_the_quaternions(male50):
    """A ball's slice of qpos is the quaternion of its segment's rotation from rest."""
    pose = _arm_pose(male50)
    q = mujoco_qpos(male50, pose)
    s = mujoco_qpos_slices(male50)["left_forearm_ball"]
    fk = db.forward(male50, pose)
    i = male50.segment_index("left_forearm")
    R_socket = np.asarray(fk.R_world_twisted[male50.parent[i]] @ male50.R_parent_socket[i])
    Q = np.asarray(male50.R_socket_rest[i]).T @ R_socket.T @ np.asarray(fk.R_world_twisted[i])
    w, x, y, z = q[s]
    axis_angle = 2 * np.arctan2(np.linalg.norm([x, y, z]), w)
    assert axis_angle == pytest.approx(np.arccos((np.trace(Q) - 1) / 2), abs=1e-9)
    assert jax.numpy.ndim(q) == 1
