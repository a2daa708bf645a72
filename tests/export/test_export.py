"""Exporters (diffbody.export: MJCF and URDF) against MuJoCo itself and an independent
NumPy URDF reader.

References: MuJoCo's own kinematics (`mj_kinematics`) on the exported MJCF (ball joints, and
the ZYZ hinges) and on the URDF (MuJoCo's URDF loader), and a URDF forward kinematics written
here from the URDF specification (origin xyz, rpy = Rz(yaw) Ry(pitch) Rx(roll), then a
rotation about the joint axis by the joint value), all against `diffbody.forward` to 1e-9.
"""

import math
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.export import SingularJointsWarning
from diffbody.export._mjcf import (
    export_mjcf,
    mujoco_joint_names,
    mujoco_qpos,
    mujoco_qpos_slices,
)
from diffbody.export._rigid_links import TINY_MASS, quat_wxyz, rpy
from diffbody.export._urdf import export_urdf, urdf_joint_values

TOL = 1e-9
CHAIN = ("left_clavicle", "left_hand")


def random_poses(body, rng, k, *, zero_tau=False, position=None):
    """k poses: theta uniform, phi in [0, pi] with some exact poles, tau in [-1, 1] (zero on
    every segment with spheres if zero_tau), random positions (or `position`)."""
    n = body.n_segments
    theta = rng.uniform(-np.pi, np.pi, (k, n))
    phi = rng.uniform(0.0, np.pi, (k, n))
    poles = rng.uniform(size=(k, n))
    phi = np.where(poles < 0.15, 0.0, np.where(poles > 0.85, np.pi, phi))
    tau = rng.uniform(-1.0, 1.0, (k, n))
    if zero_tau:
        tau[:, np.unique(np.asarray(body.sphere_segment))] = 0.0
    pos = rng.uniform(-1.0, 1.0, (k, 3)) if position is None else np.tile(position, (k, 1))
    return [
        db.Pose(jnp.asarray(pos[j]), jnp.asarray(np.stack([theta[j], phi[j], tau[j]], -1)))
        for j in range(k)
    ]


def stack(poses):
    return jax.tree.map(lambda *x: jnp.stack(x), *poses)


# --- MJCF against MuJoCo ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def mj_model(male50, tmp_path_factory):
    """The default export: a free joint and a ball per segment."""
    mujoco = pytest.importorskip("mujoco")
    path = export_mjcf(male50, tmp_path_factory.mktemp("mjcf") / "male50.xml")
    return mujoco.MjModel.from_xml_path(str(path))


@pytest.fixture(scope="module")
def mj_hinge_model(male50, tmp_path_factory):
    """The ZYZ hinge export (joints="hinges"), which warns of its singularity at rest."""
    mujoco = pytest.importorskip("mujoco")
    with pytest.warns(SingularJointsWarning, match="singular at phi = 0"):
        path = export_mjcf(
            male50, tmp_path_factory.mktemp("mjcf") / "male50_hinges.xml", joints="hinges"
        )
    return mujoco.MjModel.from_xml_path(str(path))


@pytest.fixture(scope="module", params=["ball", "hinges"])
def mj_models(request, mj_model, mj_hinge_model):
    """(joints, model) for both joint models."""
    return request.param, mj_model if request.param == "ball" else mj_hinge_model


def _mj_state(model, qpos):
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return data


def _ids(model, kind, names):
    import mujoco

    obj = {
        "body": mujoco.mjtObj.mjOBJ_BODY,
        "geom": mujoco.mjtObj.mjOBJ_GEOM,
        "site": mujoco.mjtObj.mjOBJ_SITE,
    }[kind]
    ids = [mujoco.mj_name2id(model, obj, name) for name in names]
    assert min(ids) >= 0, f"missing {kind} in the MJCF"
    return ids


def test_mjcf_structure_and_masses(male50, mj_models):
    joints, model = mj_models
    n = male50.n_segments
    assert model.nq == (7 + 4 * (n - 1) if joints == "ball" else 3 + 3 * n)
    names = mujoco_joint_names(male50, joints)
    assert [model.joint(j).name for j in range(model.njnt)] == list(names)
    slices = mujoco_qpos_slices(male50, joints)
    assert list(slices) == list(names)
    assert [s.start for s in slices.values()] == list(model.jnt_qposadr)
    assert max(s.stop for s in slices.values()) == model.nq
    bodies = _ids(model, "body", male50.segment_names)
    masses = np.asarray(male50.masses)
    np.testing.assert_allclose(model.body_mass[bodies], np.where(masses > 0, masses, TINY_MASS))
    n_tiny = int(np.sum(masses == 0))
    assert math.isclose(model.body_mass.sum(), masses.sum() + n_tiny * TINY_MASS, rel_tol=1e-12)
    assert model.ngeom == male50.n_spheres
    geoms = _ids(
        model,
        "geom",
        [f"{male50.segment_names[s]}_sphere_{k}" for k, s in enumerate(male50.sphere_segment)],
    )
    np.testing.assert_array_equal(model.geom_size[geoms, 0], np.asarray(male50.sphere_radii))
    # The keyframe is the standard position.
    rest = mujoco_qpos(male50, male50.rest_pose(), joints)
    np.testing.assert_allclose(model.key_qpos[0], rest)
    if joints == "ball":
        # qpos0 is the standard position: every ball at the identity quaternion.
        np.testing.assert_allclose(model.qpos0, rest, rtol=0, atol=1e-15)
        balls = rest[7:].reshape(-1, 4)
        np.testing.assert_allclose(balls, np.tile([1.0, 0, 0, 0], (n - 1, 1)), atol=1e-15)


def test_mjcf_mass_matrix_regular_at_the_poles(mj_models):
    """qpos = 0 and the standard position: for the hinges (every segment at its socket's
    pole, hanging limbs at phi = pi) theta and twist share an axis, and the joints'
    armature keeps MuJoCo's mass matrix regular there; the dynamics run without warnings."""
    import mujoco

    _, model = mj_models
    data = mujoco.MjData(model)
    for key in (None, 0):
        if key is not None:
            mujoco.mj_resetDataKeyframe(model, data, key)
        mujoco.mj_forward(model, data)
        mujoco.mj_step(model, data)
        assert not any(w.number for w in data.warning)
        assert np.all(np.isfinite(data.qacc))


def test_mjcf_kinematics_match_forward(male50, fk_male50, mj_models):
    """xpos = proximal joint, xmat = twisted frame, joint sites exact for any pose, the
    standard position included; sphere geoms and feature sites exact where the segments
    carrying them have no twist."""
    (joints, model), body = mj_models, male50
    rng = np.random.default_rng(7)
    poses = random_poses(body, rng, 10) + random_poses(body, rng, 9, zero_tau=True)
    poses.append(body.rest_pose())
    qpos = mujoco_qpos(body, stack(poses), joints)
    assert qpos.shape == (20, model.nq)
    np.testing.assert_allclose(qpos[3], mujoco_qpos(body, poses[3], joints), rtol=0, atol=1e-15)
    bodies = _ids(model, "body", body.segment_names)
    joint_sites = _ids(model, "site", [body.joint_names[j] for j in body.distal_joint])
    geoms = _ids(
        model,
        "geom",
        [f"{body.segment_names[s]}_sphere_{k}" for k, s in enumerate(body.sphere_segment)],
    )
    features = _ids(model, "site", body.feature_names)
    proximal, distal = list(body.proximal_joint), list(body.distal_joint)
    for j, pose in enumerate(poses):
        fk = fk_male50(pose)
        data = _mj_state(model, qpos[j])
        joints = np.asarray(fk.joint_positions)
        np.testing.assert_allclose(data.xpos[bodies], joints[proximal], rtol=0, atol=TOL)
        np.testing.assert_allclose(
            data.xmat[bodies].reshape(-1, 3, 3), np.asarray(fk.R_world_twisted), rtol=0, atol=TOL
        )
        np.testing.assert_allclose(data.site_xpos[joint_sites], joints[distal], rtol=0, atol=TOL)
        if j >= 10:  # tau = 0 on every segment with spheres
            np.testing.assert_allclose(
                data.geom_xpos[geoms], np.asarray(fk.sphere_centers), rtol=0, atol=TOL
            )
            np.testing.assert_allclose(
                data.site_xpos[features], np.asarray(fk.feature_points), rtol=0, atol=TOL
            )


def test_mjcf_twisted_spheres_turn_fully(male50, fk_male50, mj_model):
    """With twist, a rigid link turns its spheres by the full tau; diffbody by tau z / L.
    The distal-most sphere of the forearm (z >= L) agrees, a proximal one does not."""
    body = male50
    i = body.segment_index("left_forearm")
    pose = body.rest_pose()
    pose = db.Pose(pose.position, pose.angles.at[i, 2].set(0.8))
    data = _mj_state(mj_model, mujoco_qpos(body, pose))
    fk = fk_male50(pose)
    k = body.segment_spheres("left_forearm")
    z = np.asarray(body.sphere_origins)[k, 2] / float(body.lengths[i])
    geoms = _ids(mj_model, "geom", [f"left_forearm_sphere_{s}" for s in k])
    gap = np.linalg.norm(data.geom_xpos[geoms] - np.asarray(fk.sphere_centers)[k], axis=1)
    assert np.all(gap[z >= 1.0] < TOL)
    r = np.linalg.norm(np.asarray(body.sphere_origins)[k, :2], axis=1)
    expected = 2 * r * np.abs(np.sin(0.8 * (1 - np.clip(z, 0, 1)) / 2))  # chord of the gap
    np.testing.assert_allclose(gap, expected, rtol=0, atol=TOL)


def test_mjcf_reroot(male50, fk_male50, mj_models):
    """A re-rooted body's poses put the MJCF where `Body.with_root` says: the root joint at
    the pose's position, the segment ending there turned by the whole body's orientation
    from its standard frame, and the body rigidly moved from where the default root puts it."""
    joints, mj_model = mj_models
    body = male50.with_root("left_toe_tip")
    foot = body.segment_index("left_foot")
    bodies = _ids(mj_model, "body", body.segment_names)
    (toe,) = _ids(mj_model, "site", ["left_toe_tip"])
    for pose in random_poses(body, np.random.default_rng(3), 2):
        data = _mj_state(mj_model, mujoco_qpos(body, pose, joints))
        fk = fk_male50(pose)  # the same pose, default root
        R_mj = data.xmat[bodies].reshape(-1, 3, 3)
        R_fk = np.asarray(fk.R_world_twisted)
        np.testing.assert_allclose(data.site_xpos[toe], np.asarray(pose.position), atol=TOL)
        np.testing.assert_allclose(
            R_mj[foot], R_fk[0] @ np.asarray(body.R_world_pin_rest), rtol=0, atol=TOL
        )
        Rc = R_mj[foot] @ R_fk[foot].T
        np.testing.assert_allclose(R_mj, Rc @ R_fk, rtol=0, atol=TOL)
        p_fk = np.asarray(fk.joint_positions)[list(body.proximal_joint)]
        np.testing.assert_allclose(
            data.xpos[bodies] - data.site_xpos[toe],
            (p_fk - np.asarray(fk.joint_positions[body.joint_index("left_toe_tip")])) @ Rc.T,
            rtol=0,
            atol=TOL,
        )


# --- poses with a moved spine -----------------------------------------------------------------
SPINE_CHANGE = (0.3, 0.2, -0.15)  # rad, (flexion, axial, lateral) beyond the rest sum
# Limb rows within their limits, as (w_x, w_y, tau): swing vector and twist (rad).
LIMB_MOVES = {
    "left_upper_arm": (1.2, 0.8, 0.6),
    "right_upper_arm": (-0.5, 1.0, -0.4),
    "left_forearm": (0.0, 1.2, 0.9),
    "right_forearm": (0.0, 0.7, -0.7),
    "left_thigh": (0.3, 0.9, 0.3),
    "right_shank": (0.0, -1.0, 0.0),
    "left_foot": (0.0, 0.2, -0.3),
    "head": (0.3, -0.2, 0.5),
}
SPINE_CASES = ("target", "bent", "target_rerooted", "bent_rerooted")


def _limb_pose(body):
    """The standard position with the limbs of `LIMB_MOVES` moved (within their limits)."""
    rest = body.rest_pose()
    idx = np.array([body.segment_index(name) for name in LIMB_MOVES])
    moves = np.array(list(LIMB_MOVES.values()))
    swing = np.zeros((body.n_segments, 2))
    twist = np.zeros(body.n_segments)
    swing[idx], twist[idx] = moves[:, :2], moves[:, 2]
    rows = db.angles_from_swing(body, jnp.asarray(swing), jnp.asarray(twist))[idx]
    pose = db.Pose(rest.position, rest.angles.at[idx].set(rows))
    assert bool(jnp.all(db.within_limits(body, pose)))
    return pose


@pytest.fixture(scope="module")
def rerooted(male50):
    return male50.with_root("left_toe_tip")


@pytest.fixture(scope="module")
def spine_cases(male50, fk_male50, rerooted):
    """{case: (body, compiled forward, pose)}: the limbs of `LIMB_MOVES` moved and the spine
    bent by a spine target, or by `bend_pose` to the same target; both also on a body
    re-rooted at the left toe tip, that toe at its standard place."""
    spine = male50.spine
    target = jnp.sum(spine.rest, axis=0) + jnp.asarray(SPINE_CHANGE)
    limbs = _limb_pose(male50)
    with_target = db.Pose(limbs.position, limbs.angles, target)
    # Compiled: eager Bendspine takes several times its compile time.
    bend = jax.jit(
        lambda pose: db.bend_pose(male50, spine, pose, target, initiator=spine.initiator)
    )
    bent, _ = bend(limbs)
    vertebrae = np.array([male50.segment_index(name) for name in spine.segment_names])
    assert np.ptp(np.asarray(bent.angles - limbs.angles)[vertebrae]) > 0.01
    fk_rerooted = jax.jit(lambda pose: db.forward(rerooted, pose))
    at_toe = lambda pose: db.Pose(rerooted.rest_position, pose.angles, pose.spine_target)  # noqa: E731
    return {
        "target": (male50, fk_male50, with_target),
        "bent": (male50, fk_male50, bent),
        "target_rerooted": (rerooted, fk_rerooted, at_toe(with_target)),
        "bent_rerooted": (rerooted, fk_rerooted, at_toe(bent)),
    }


def _rigid_points(body, fk, segments, local):
    """Points fixed in their segments' twisted frames (the export's rigid links), world."""
    R = np.asarray(fk.R_world_twisted)[segments]
    p = np.asarray(fk.joint_positions)[np.asarray(body.proximal_joint)[segments]]
    return p + np.einsum("kij,kj->ki", R, local)


@pytest.mark.parametrize("case", SPINE_CASES)
def test_mjcf_moved_spine_matches_forward(spine_cases, mj_models, case):
    """Poses whose spine is bent (by a spine target or by `bend_pose`), also re-rooted: every
    joint and twisted frame where `forward` puts them; spheres and feature sites where the
    rigid links carry them (full twist, module docstring)."""
    body, fk_fn, pose = spine_cases[case]
    joints, model = mj_models
    fk = fk_fn(pose)
    data = _mj_state(model, mujoco_qpos(body, pose, joints))
    joints = np.asarray(fk.joint_positions)
    bodies = _ids(model, "body", body.segment_names)
    joint_sites = _ids(model, "site", [body.joint_names[j] for j in body.distal_joint])
    np.testing.assert_allclose(
        data.xpos[bodies], joints[list(body.proximal_joint)], rtol=0, atol=TOL
    )
    np.testing.assert_allclose(
        data.site_xpos[joint_sites], joints[list(body.distal_joint)], rtol=0, atol=TOL
    )
    np.testing.assert_allclose(
        data.xmat[bodies].reshape(-1, 3, 3), np.asarray(fk.R_world_twisted), rtol=0, atol=TOL
    )
    sph_seg = np.asarray(body.sphere_segment)
    origins = np.asarray(body.sphere_origins)
    geoms = _ids(
        model, "geom", [f"{body.segment_names[s]}_sphere_{k}" for k, s in enumerate(sph_seg)]
    )
    np.testing.assert_allclose(
        data.geom_xpos[geoms], _rigid_points(body, fk, sph_seg, origins), rtol=0, atol=TOL
    )
    f_sph = np.asarray(body.feature_sphere)
    local = origins[f_sph] + np.asarray(body.sphere_radii)[f_sph, None] * np.asarray(
        body.feature_directions
    )
    features = _ids(model, "site", body.feature_names)
    np.testing.assert_allclose(
        data.site_xpos[features], _rigid_points(body, fk, sph_seg[f_sph], local), rtol=0, atol=TOL
    )
    # The twisted limbs and head carry features away from their distal ends, so the rigid
    # links and diffbody's partial twist do differ there (by centimetres).
    gap = np.linalg.norm(data.site_xpos[features] - np.asarray(fk.feature_points), axis=1)
    assert gap.max() > 0.01


def test_mujoco_qpos_spine_target_rows(male50, spine_cases):
    """With a spine target, the limbs keep their pose angles as hinge values and the
    vertebra rows of the pose are not used (the target sets them)."""
    _, _, pose = spine_cases["target"]
    names = mujoco_joint_names(male50, "hinges")
    q = mujoco_qpos(male50, pose, "hinges")
    for seg in LIMB_MOVES:
        i = male50.segment_index(seg)
        for k, hinge in enumerate(("theta", "phi")):
            assert q[names.index(f"{seg}_{hinge}")] == float(pose.angles[i, k])
    vertebrae = np.array([male50.segment_index(name) for name in male50.spine.segment_names])
    moved = pose.angles.at[vertebrae].add(0.2)
    for joints in ("hinges", "ball"):
        q = mujoco_qpos(male50, pose, joints)
        q_moved = mujoco_qpos(male50, db.Pose(pose.position, moved, pose.spine_target), joints)
        np.testing.assert_array_equal(q_moved, q)


# --- URDF against an independent reader -------------------------------------------------------
def _rot_axis(axis, q):
    """Rotation by q about the unit axis (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(q) * K + (1 - math.cos(q)) * K @ K


def _rpy_matrix(roll, pitch, yaw):
    """URDF: fixed-axis roll about X, then pitch about Y, then yaw about Z."""
    return _rot_axis([0, 0, 1], yaw) @ _rot_axis([0, 1, 0], pitch) @ _rot_axis([1, 0, 0], roll)


def _floats(text, n=3):
    values = [float(v) for v in (text or " ".join(["0"] * n)).split()]
    assert len(values) == n
    return np.array(values)


def urdf_link_frames(path, values):
    """World (root link) frames {link: (R, p)} of a URDF for joint values {name: q}."""
    robot = ET.parse(path).getroot()
    assert robot.tag == "robot"
    children = {}
    for joint in robot.findall("joint"):
        origin = joint.find("origin")
        R0 = _rpy_matrix(*_floats(origin.get("rpy")))
        p0 = _floats(origin.get("xyz"))
        kind = joint.get("type")
        axis = joint.find("axis")
        if kind == "fixed":
            R_joint = np.eye(3)
        else:
            assert kind == "revolute"
            R_joint = _rot_axis(_floats(axis.get("xyz")), values[joint.get("name")])
        parent, child = joint.find("parent").get("link"), joint.find("child").get("link")
        children.setdefault(parent, []).append((child, R0 @ R_joint, p0))
    links = [link.get("name") for link in robot.findall("link")]
    child_links = {c for kids in children.values() for c, _, _ in kids}
    (root,) = [name for name in links if name not in child_links]
    frames, todo = {root: (np.eye(3), np.zeros(3))}, [root]
    while todo:
        name = todo.pop()
        R, p = frames[name]
        for child, R_rel, p_rel in children.get(name, ()):
            frames[child] = (R @ R_rel, p + R @ p_rel)
            todo.append(child)
    assert set(frames) == set(links)
    return robot, frames


def test_urdf_whole_tree_matches_forward(male50, fk_male50, tmp_path):
    body = male50
    path = export_urdf(body, tmp_path / "male50.urdf")
    rest = body.rest_pose()
    rng = np.random.default_rng(11)
    poses = random_poses(body, rng, 8, position=np.asarray(body.rest_position))
    # The whole body is fixed at its standard placement in the URDF.
    poses = [db.Pose(p.position, p.angles.at[0].set(rest.angles[0])) for p in poses]
    for pose in poses + [rest]:
        values = urdf_joint_values(body, pose)
        robot, frames = urdf_link_frames(path, values)
        revolute = [j.get("name") for j in robot.findall("joint") if j.get("type") == "revolute"]
        assert sorted(values) == sorted(revolute)
        fk = fk_male50(pose)
        joints = np.asarray(fk.joint_positions)
        for i, seg in enumerate(body.segment_names):
            R, p = frames[seg]
            np.testing.assert_allclose(R, np.asarray(fk.R_world_twisted[i]), rtol=0, atol=TOL)
            np.testing.assert_allclose(p, joints[body.proximal_joint[i]], rtol=0, atol=TOL)
    # Inertials and spheres.
    masses = [float(m.get("value")) for m in robot.iter("mass")]
    n_virtual = len(masses) - body.n_segments + int(np.sum(np.asarray(body.masses) == 0))
    assert math.isclose(
        sum(masses), float(body.masses.sum()) + n_virtual * TINY_MASS, rel_tol=1e-12
    )
    radii = sorted(
        float(s.get("radius")) for c in robot.iter("collision") for s in c.iter("sphere")
    )
    np.testing.assert_array_equal(radii, np.sort(np.asarray(body.sphere_radii)))


def test_urdf_chain_matches_forward(male50, fk_male50, tmp_path):
    body = male50
    path = export_urdf(body, tmp_path / "arm.urdf", chain=CHAIN, name="left_arm")
    chain = ["left_clavicle", "left_upper_arm", "left_forearm", "left_hand"]
    up = body.parent[body.segment_index(CHAIN[0])]
    rng = np.random.default_rng(5)
    for pose in random_poses(body, rng, 8):
        values = urdf_joint_values(body, pose, chain=CHAIN)
        assert sorted(values) == sorted(f"{s}_hinge{k}" for s in chain for k in range(3))
        robot, frames = urdf_link_frames(path, values)
        assert robot.get("name") == "left_arm"
        assert set(frames) == {"base"} | {
            f"{s}{x}" for s in chain for x in ("", "_hinge0_link", "_hinge1_link")
        }
        fk = fk_male50(pose)
        R_up = np.asarray(fk.R_world_twisted[up])
        p_up = np.asarray(fk.joint_positions[body.proximal_joint[up]])
        for seg in chain:
            i = body.segment_index(seg)
            R, p = frames[seg]
            np.testing.assert_allclose(
                R, R_up.T @ np.asarray(fk.R_world_twisted[i]), rtol=0, atol=TOL
            )
            np.testing.assert_allclose(
                p,
                R_up.T @ (np.asarray(fk.joint_positions[body.proximal_joint[i]]) - p_up),
                rtol=0,
                atol=TOL,
            )


@pytest.mark.parametrize("case", SPINE_CASES)
def test_urdf_moved_spine_matches_forward(spine_cases, tmp_path_factory, case):
    """The same poses in the URDF: link frames as `forward`'s relative to the whole body (the
    file fixes the whole body at its standard placement, where the default-root poses
    leave it; a re-rooted body moves it)."""
    body, fk_fn, pose = spine_cases[case]
    path = export_urdf(body, tmp_path_factory.mktemp("urdf") / "body.urdf")
    values = urdf_joint_values(body, pose)
    robot, frames = urdf_link_frames(path, values)
    fk = fk_fn(pose)
    R_fk, joints = np.asarray(fk.R_world_twisted), np.asarray(fk.joint_positions)
    p_fk = joints[list(body.proximal_joint)]
    R0, p0 = frames[body.segment_names[0]]
    if not case.endswith("rerooted"):
        np.testing.assert_allclose(R0, R_fk[0], rtol=0, atol=TOL)
        np.testing.assert_allclose(p0, p_fk[0], rtol=0, atol=TOL)
    for i, seg in enumerate(body.segment_names):
        R, p = frames[seg]
        np.testing.assert_allclose(R0.T @ R, R_fk[0].T @ R_fk[i], rtol=0, atol=TOL)
        np.testing.assert_allclose(
            R0.T @ (p - p0), R_fk[0].T @ (p_fk[i] - p_fk[0]), rtol=0, atol=TOL
        )
    for joint in robot.findall("joint"):
        if joint.get("type") == "revolute":
            limit = joint.find("limit")
            q = values[joint.get("name")]
            assert float(limit.get("lower")) <= q <= float(limit.get("upper")), joint.get("name")


def test_rotation_conversions_round_trip():
    """The quaternions and rpy written to the files, for random rotations and at gimbal lock."""
    rng = np.random.default_rng(0)
    mats = [_rpy_matrix(*rng.uniform(-np.pi, np.pi, 3)) for _ in range(200)]
    mats += [
        _rpy_matrix(r, s * np.pi / 2, y) for r, y in rng.uniform(-3, 3, (10, 2)) for s in (-1, 1)
    ]
    mats += [
        _rpy_matrix(0.3, np.pi / 2 - 1e-9, -1.2),
        np.diag([1.0, -1.0, -1.0]),
        np.diag([-1.0, 1.0, -1.0]),
        np.diag([-1.0, -1.0, 1.0]),
        np.eye(3),
    ]
    for R in mats:
        np.testing.assert_allclose(_rpy_matrix(*rpy(R)), R, rtol=0, atol=1e-14)
        w, x, y, z = quat_wxyz(R)
        assert w >= 0
        Q = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(Q, R, rtol=0, atol=1e-14)


# --- bad input --------------------------------------------------------------------------------
def test_unknown_chain_segment_lists_valid_names(male50, tmp_path):
    with pytest.raises(KeyError, match="left_hnd.*left_hand"):
        export_urdf(male50, tmp_path / "x.urdf", chain=("left_clavicle", "left_hnd"))
    with pytest.raises(KeyError, match="Valid segments: whole_body"):
        urdf_joint_values(male50, male50.rest_pose(), chain=("shoulder", "left_hand"))


@pytest.mark.parametrize("chain", [("left_hand", "left_clavicle"), ("left_clavicle", "right_hand")])
def test_chain_not_below_first_names_both(male50, tmp_path, chain):
    with pytest.raises(ValueError, match=f"{chain[1]!r} is not below {chain[0]!r}"):
        export_urdf(male50, tmp_path / "x.urdf", chain=chain)
    with pytest.raises(ValueError, match="is not below"):
        urdf_joint_values(male50, male50.rest_pose(), chain=chain)


def test_bad_pose_shape(male50):
    bad = db.Pose(male50.rest_position, jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="mujoco_qpos: expected angles"):
        mujoco_qpos(male50, bad)
    with pytest.raises(ValueError, match="urdf_joint_values: expected angles"):
        urdf_joint_values(male50, bad)


def test_unknown_joint_model(male50, tmp_path):
    with pytest.raises(ValueError, match="joints must be one of"):
        export_mjcf(male50, tmp_path / "x.xml", joints="balls")
    with pytest.raises(ValueError, match="joints must be one of"):
        mujoco_qpos(male50, male50.rest_pose(), joints="zyz")
