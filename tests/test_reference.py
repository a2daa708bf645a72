"""diffbody's forward kinematics against the independent plain-NumPy reference in helpers.py.

Float64 throughout; every quantity (joints, base and twisted frames, sphere centres and
radii, features, centre of gravity) must agree to ATOL = 1e-10 m (or 1e-10 in a rotation
matrix entry). Runs on a small hand-written body that exercises every cross-of-axes case
(+Z, -Z, +-Y, -X, forward and oblique directions), all four limb tables, spheres and
centroids beyond both ends of their segment, and on the default male50 body when its file
exists.
"""

import json
import math
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import diffbody as db  # noqa: E402

try:
    from . import helpers as H  # noqa: E402
except ImportError:  # tests/ is not a package; pytest puts tests/ on sys.path
    import helpers as H  # noqa: E402

ATOL = 1e-10
WB = "whole_body"
DATA = Path(__file__).resolve().parent.parent / "data"


# --- a small body ------------------------------------------------------------------------------
def _seg(
    name,
    proximal,
    distal,
    length,
    direction,
    *,
    std="swing",
    mass=1.0,
    centroid=None,
    spheres=(),
    limits=None,
):
    seg = {
        "name": name,
        "proximal": proximal,
        "distal": distal,
        "length": length,
        "direction": direction,
        "limits": limits or {"kind": "free"},
        "mass": mass,
        "centroid": centroid if centroid is not None else [0.01, -0.005, length / 2],
        "spheres": list(spheres),
    }
    if std != "swing":
        seg["standard_orientation"] = std
    return seg


def _sph(origin, radius, **features):
    s = {"origin": origin, "radius": radius}
    if features:
        s["features"] = [{"name": k, "direction": v} for k, v in features.items()]
    return s


BOX = {"kind": "box", "swing_x_deg": [-40, 40], "swing_y_deg": [-30, 60], "twist_deg": [-45, 45]}
CONE = {"kind": "cone", "swing_max_deg": 120, "twist_deg": [-90, 90]}
HINGE = {"kind": "hinge", "swing_y_deg": [0, 150], "twist_deg": [-80, 80]}


def _limb(side, kind_arm):
    """Shoulder girdle or pelvis piece, then a limb (table), a swing segment, an extremity."""
    s = 1.0 if side == "left" else -1.0
    if kind_arm:
        girdle = _seg(
            f"{side}_clavicle",
            "neck_base",
            f"{side}_shoulder",
            0.18,
            [0, s, 0],
            mass=0.8,
            spheres=[_sph([0.0, 0.0, 0.1], 0.04)],
        )
        upper = _seg(
            f"{side}_upper_arm",
            f"{side}_shoulder",
            f"{side}_elbow",
            0.3,
            [0, 0, -1],
            std=f"{side}_arm",
            mass=2.0,
            centroid=[0.01, 0.02 * s, 0.13],
            limits=CONE,
            spheres=[
                _sph([0.0, 0.0, -0.02], 0.06),
                _sph([0.01, 0.0, 0.15], 0.05, outer=[0, -s, 0]),
                _sph([0.0, 0.01, 0.29], 0.045),
            ],
        )
        lower = _seg(
            f"{side}_forearm",
            f"{side}_elbow",
            f"{side}_wrist",
            0.27,
            [0, 0, -1],
            mass=1.2,
            limits=HINGE,
            spheres=[_sph([0.0, 0.0, 0.1], 0.045), _sph([0.005, -0.01, 0.25], 0.035)],
        )
        end = _seg(
            f"{side}_hand",
            f"{side}_wrist",
            f"{side}_fingertip",
            0.18,
            [0, 0, -1],
            mass=0.45,
            limits=BOX,
            spheres=[
                _sph([0.0, 0.0, 0.06], 0.04, palm=[0, s, 0], back=[0, -s, 0.1]),
                _sph([0.01, 0.0, 0.2], 0.02, tip=[0, 0, 1]),
            ],
        )
    else:
        girdle = _seg(
            f"{side}_pelvis",
            "center_hip",
            f"{side}_hip",
            0.09,
            [0, s, 0],
            mass=3.0,
            spheres=[_sph([0.0, 0.0, 0.05], 0.08)],
        )
        upper = _seg(
            f"{side}_thigh",
            f"{side}_hip",
            f"{side}_knee",
            0.43,
            [0, 0, -1],
            std=f"{side}_leg",
            mass=8.0,
            centroid=[0.0, 0.0, 0.18],
            limits=BOX,
            spheres=[_sph([0.0, 0.0, 0.05], 0.09), _sph([0.02, 0.0, 0.3], 0.07, front=[1, 0, 0])],
        )
        lower = _seg(
            f"{side}_shank",
            f"{side}_knee",
            f"{side}_ankle",
            0.42,
            [0, 0, -1],
            mass=3.5,
            limits=HINGE,
            spheres=[_sph([0.0, 0.0, 0.1], 0.06), _sph([-0.01, 0.0, 0.45], 0.04)],
        )
        foot_dir = [1, 0, 0] if side == "right" else [1.0, 0.05, -0.1]
        end = _seg(
            f"{side}_foot",
            f"{side}_ankle",
            f"{side}_toe",
            0.2,
            foot_dir,
            mass=1.0,
            limits=CONE,
            spheres=[
                _sph([0.0, 0.0, 0.05], 0.04, heel=[-0.2, 0, -1]),
                _sph([-0.02, 0.0, 0.17], 0.03, toe=[0, 0, 1]),
            ],
        )
    return [girdle, upper, lower, end]


SMALL_BODY = {
    "schema": "diffbody.body/1",
    "name": "small_reference_body",
    "description": "a hand-made body for the reference FK test",
    "sources": ["tests/test_reference.py"],
    "root_joint": "center_hip",
    "segments": [
        # Not in tree order on purpose.
        *_limb("left", True),
        _seg(
            "lumbar",
            "center_hip",
            "waist",
            0.2,
            [0, 0, 1],
            mass=10.0,
            centroid=[0.01, 0.0, 0.1],
            limits=BOX,
            spheres=[
                _sph([0.0, 0.0, 0.1], 0.12, belly=[1, 0, 0]),
                _sph([0.02, 0.03, 0.25], 0.1, side=[0, 1, 0]),
                _sph([0.0, 0.05, -0.03], 0.1),
            ],
        ),
        _seg(
            "thorax",
            "waist",
            "neck_base",
            0.3,
            [0, 0, 1],
            mass=20.0,
            centroid=[0.02, 0.0, 0.35],
            limits=CONE,
            spheres=[
                _sph([0.03, 0.0, 0.15], 0.15, sternum=[1, 0, 0.2]),
                _sph([-0.02, 0.08, 0.28], 0.08),
            ],
        ),
        _seg(
            "head",
            "neck_base",
            "head_top",
            0.25,
            [0.1, 0.0, 1.0],
            mass=5.0,
            centroid=[0.01, 0.0, -0.02],
            spheres=[_sph([0.02, 0.0, 0.14], 0.1, nose=[1, 0, 0], left_ear=[0, 1, 0])],
        ),
        _seg(
            "tail",
            "center_hip",
            "tail_tip",
            0.1,
            [-1, 0, 0],
            mass=0.0,
            spheres=[_sph([0.0, 0.01, 0.08], 0.02, tip=[0, 0, 1])],
        ),
        *_limb("right", True),
        *_limb("left", False),
        *_limb("right", False),
    ],
}


# --- fixtures ----------------------------------------------------------------------------------
class Case:
    """A body file, diffbody's Body from it, and diffbody's FK jitted once."""

    def __init__(self, path: Path, body=None):
        self.doc = H.load_json_body(path)
        self.body = db.load_body(path) if body is None else body
        # One compilation per body, reused by every pose (unbatched: compiles faster than
        # a vmapped one, and a batch of another size would compile again).
        self.fk = jax.jit(db.forward)


@pytest.fixture(scope="module", params=["small", "male50"])
def case(request, tmp_path_factory):
    if request.param == "small":
        path = tmp_path_factory.mktemp("bodies") / "body_small.json"
        path.write_text(json.dumps(SMALL_BODY, indent=1), encoding="utf-8")
        return Case(path)
    path = DATA / f"body_{request.param}.json"
    if not path.is_file():
        pytest.skip(f"{path} not written yet")
    try:  # the session's body from conftest.py, if it has one: loading takes seconds
        body = request.getfixturevalue(request.param)
    except pytest.FixtureLookupError:
        body = None
    return Case(path, body)


# --- comparison --------------------------------------------------------------------------------
def _angles_dict(body, angles) -> dict:
    return {n: tuple(float(a) for a in angles[i]) for i, n in enumerate(body.segment_names)}


def _sphere_keys(body) -> list[tuple[str, int]]:
    """(segment name, index within the segment) of each of diffbody's spheres."""
    counts: dict[str, int] = {}
    keys = []
    for i in body.sphere_segment:
        name = body.segment_names[i]
        keys.append((name, counts.get(name, 0)))
        counts[name] = counts.get(name, 0) + 1
    return keys


def _check(actual, expected, names, what: str, where: str) -> None:
    """assert |actual - expected| <= ATOL entrywise; a failure names the worst item."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, (where, what, actual.shape, expected.shape)
    err = np.abs(actual - expected).reshape(len(names), -1).max(axis=1)
    if not np.all(err <= ATOL):  # also catches NaN
        k = int(np.nanargmax(np.where(np.isnan(err), np.inf, err)))
        bad = [names[i] for i in np.flatnonzero(~(err <= ATOL))]
        raise AssertionError(
            f"{where}: {what} of {names[k]} differs by {err[k]:.3g} (> {ATOL}); "
            f"diffbody {actual[k].tolist()}, reference {expected[k].tolist()}; "
            f"{len(bad)} differing: {bad[:8]}"
        )


def _compare(case: Case, positions: np.ndarray, angles: np.ndarray, label: str) -> None:
    """diffbody's FK of each pose against the reference, quantity by quantity."""
    body, doc = case.body, case.doc
    keys = _sphere_keys(body)
    seg_names = list(body.segment_names)
    assert set(seg_names) == {WB} | {s["name"] for s in doc["segments"]}
    assert body.joint_names[0] == "center_of_gravity"
    for b in range(len(positions)):
        pose = db.Pose(position=jnp.asarray(positions[b]), angles=jnp.asarray(angles[b]))
        fk = jax.tree_util.tree_map(np.asarray, case.fk(body, pose))
        ref = H.reference_forward(doc, positions[b], _angles_dict(body, angles[b]))
        where = f"{label}, pose {b}"

        # Joints: row 0 ("center_of_gravity") carries the root position.
        assert set(body.joint_names[1:]) == set(ref["joints"])
        _check(
            fk.joint_positions,
            [positions[b]] + [ref["joints"][n] for n in body.joint_names[1:]],
            body.joint_names,
            "joint position",
            where,
        )
        _check(
            fk.R_world_base,
            [ref["frames_base"][n] for n in seg_names],
            seg_names,
            "R_world_base",
            where,
        )
        _check(
            fk.R_world_twisted,
            [ref["frames_twisted"][n] for n in seg_names],
            seg_names,
            "R_world_twisted",
            where,
        )

        ref_spheres = {(s[0], s[1]): (s[2], s[3]) for s in ref["spheres"]}
        assert set(keys) == set(ref_spheres) and len(keys) == len(ref_spheres)
        sphere_names = [f"{n}[{k}]" for n, k in keys]
        _check(
            fk.sphere_centers,
            [ref_spheres[k][0] for k in keys],
            sphere_names,
            "sphere centre",
            where,
        )
        _check(
            fk.sphere_radii, [ref_spheres[k][1] for k in keys], sphere_names, "sphere radius", where
        )

        assert set(body.feature_names) == set(ref["features"])
        _check(
            fk.feature_points,
            [ref["features"][n] for n in body.feature_names],
            body.feature_names,
            "feature point",
            where,
        )
        _check(fk.center_of_gravity[None], ref["cog"][None], ["body"], "center of gravity", where)


def _random_angles(rng, n_poses, n_seg, *, poles=0.0):
    """theta uniform in [-pi, pi], phi in [0, pi] (a share `poles` of them exactly 0 or pi),
    tau in [-1, 1]."""
    theta = rng.uniform(-math.pi, math.pi, (n_poses, n_seg))
    phi = rng.uniform(0.0, math.pi, (n_poses, n_seg))
    pick = rng.uniform(size=phi.shape) < poles
    phi = np.where(pick, rng.choice([0.0, math.pi], size=phi.shape), phi)
    tau = rng.uniform(-1.0, 1.0, (n_poses, n_seg))
    return np.stack([theta, phi, tau], axis=-1)


# --- tests: diffbody against the reference -----------------------------------------------------
def test_rest_pose(case):
    pose = case.body.rest_pose()
    positions = np.asarray(pose.position)[None]
    angles = np.asarray(pose.angles)[None]
    _compare(case, positions, angles, "rest pose")
    # In the standard position every base frame is the segment's cross of axes.
    ref = H.reference_forward(case.doc, positions[0], _angles_dict(case.body, angles[0]))
    for seg in case.doc["segments"]:
        np.testing.assert_allclose(
            ref["frames_base"][seg["name"]], H.cross_of_axes(seg["direction"]), atol=1e-12
        )


def test_random_poses(case):
    rng = np.random.default_rng(20240611)
    n = 32
    angles = _random_angles(rng, n, case.body.n_segments)
    positions = rng.uniform(-1.0, 1.0, (n, 3))
    _compare(case, positions, angles, "random pose")


def _rest_directions(case) -> dict:
    """Segment name -> (standard orientation kind, unit rest direction)."""
    out = {WB: ("swing", np.array([0.0, 0.0, 1.0]))}
    for seg in case.doc["segments"]:
        d = np.asarray(seg["direction"], dtype=float)
        out[seg["name"]] = (seg.get("standard_orientation", "swing"), d / np.linalg.norm(d))
    return out


def _near_opposite(d_rest: np.ndarray, theta: float, phi: float, angle: float) -> bool:
    return float(np.dot(H.direction(theta, phi), d_rest)) < -math.cos(angle)


def test_random_poses_at_the_poles(case):
    """phi exactly 0 or pi for many segments (limbs pointing straight up or down), the whole
    body included. A swing segment is never sent (near) opposite its rest direction here:
    see test_swing_opposite_rest_direction."""
    rng = np.random.default_rng(7)
    n = 24
    angles = _random_angles(rng, n, case.body.n_segments, poles=0.5)
    rest = _rest_directions(case)
    for i, name in enumerate(case.body.segment_names):
        kind, d_rest = rest[name]
        if kind != "swing":
            continue
        for b in range(n):
            theta, phi = angles[b, i, :2]
            if _near_opposite(d_rest, theta, phi, 1e-2):
                angles[b, i, 1] = math.pi - phi  # the other pole (or the mirror latitude)
    positions = rng.uniform(-1.0, 1.0, (n, 3))
    _compare(case, positions, angles, "pole pose")


def _opposite_pose(case, delta):
    """Every swing segment resting along +-Z sent to within delta of the opposite pole."""
    rest = _rest_directions(case)
    pose = case.body.rest_pose()
    angles = np.repeat(np.asarray(pose.angles)[None], 3, axis=0)
    moved = False
    for i, name in enumerate(case.body.segment_names):
        kind, d_rest = rest[name]
        if kind == "swing" and abs(abs(d_rest[2]) - 1.0) < 1e-12:
            phi = math.pi - delta if d_rest[2] > 0 else delta
            angles[:, i, 0] = [0.3, -2.0, 2.9]
            angles[:, i, 1] = phi
            moved = True
    assert moved
    return np.repeat(np.asarray(pose.position)[None], 3, axis=0), angles


@pytest.mark.parametrize("delta", [1e-8, 1e-6, 1e-4])
def test_swing_near_opposite_rest_direction(case, delta):
    """Regression: near the direction opposite a swing segment's rest direction the smallest
    rotation used to cancel catastrophically (errors ~1e-16 / delta**2, a reflection at the
    pole itself)."""
    positions, angles = _opposite_pose(case, delta)
    _compare(case, positions, angles, f"opposite rest direction, delta {delta}")


def test_swing_exactly_opposite_rest_direction(case):
    """Exactly opposite the rest direction the smallest rotation is not unique (the reference
    takes the limit along the pose's meridian, diffbody a fixed half-turn): whatever the
    convention, every frame must be a proper rotation, and the whole body's Z (whose socket is
    the world) the requested direction. Deeper segments hang from frames that differ by the
    convention, so their directions differ too."""
    positions, angles = _opposite_pose(case, 0.0)
    for pos, ang in zip(positions, angles):
        fk = case.fk(case.body, db.Pose(position=jnp.asarray(pos), angles=jnp.asarray(ang)))
        R = np.asarray(fk.R_world_base)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
        eye = np.broadcast_to(np.eye(3), R.shape)
        np.testing.assert_allclose(R @ R.transpose(0, 2, 1), eye, atol=1e-12)
        ref = H.reference_forward(case.doc, pos, _angles_dict(case.body, ang))
        np.testing.assert_allclose(R[0][:, 2], ref["frames_base"][WB][:, 2], atol=1e-12)


def test_twist_only_poses(case):
    """The rest directions with random twists only (every segment and the whole body): the
    twist's share along each segment turns spheres, features and centroids."""
    rng = np.random.default_rng(3)
    rest = case.body.rest_pose()
    n = 4
    angles = np.repeat(np.asarray(rest.angles)[None], n, axis=0)
    angles[:, :, 2] = rng.uniform(-1.0, 1.0, angles.shape[:2])
    positions = np.repeat(np.asarray(rest.position)[None], n, axis=0)
    _compare(case, positions, angles, "twist-only pose")


# --- tests: the reference's own tables (seed 000) ----------------------------------------------
THETAS_DEG = np.concatenate([np.linspace(-720.0, 720.0, 577), [-90, 0, 90, 180, 225, 270]])


def _mod360(x):
    return (x + 180.0) % 360.0 - 180.0


def test_left_arm_hanging_is_standard_cross_of_axes():
    """Seed 000's consistency check: at phi = 180 deg, theta - s = 180 deg (mod 360), so the
    hanging arm's frame is X forward, Y right, Z down whatever theta is."""
    for theta in THETAS_DEG:
        s = H.left_arm_twist_deg(theta, 180.0)
        assert abs(_mod360(theta - s - 180.0)) < 1e-9, theta
        R = H.rot_z(math.radians(theta)) @ H.rot_y(math.pi) @ H.rot_z(math.radians(s))
        np.testing.assert_allclose(R, np.diag([1.0, -1.0, -1.0]), atol=1e-12, err_msg=str(theta))


def test_limb_tables_at_the_poles():
    """At each pole every limb table gives one frame whatever theta is; hanging, it is the
    standard cross of axes C(-Z) = diag(1, -1, -1)."""
    hanging = H.cross_of_axes([0, 0, -1])
    np.testing.assert_allclose(hanging, np.diag([1.0, -1.0, -1.0]), atol=0)
    for kind in H.LIMBS:
        up = None
        for theta in np.linspace(-math.pi, math.pi, 73):
            s_down = H.standard_twist(kind, theta, math.pi)
            down = H.rot_z(theta) @ H.rot_y(math.pi) @ H.rot_z(s_down)
            np.testing.assert_allclose(down, hanging, atol=1e-12, err_msg=kind)
            top = H.rot_z(theta) @ H.rot_y(0.0) @ H.rot_z(H.standard_twist(kind, theta, 0.0))
            up = top if up is None else up
            np.testing.assert_allclose(top, up, atol=1e-12, err_msg=kind)


def test_left_arm_table_rows():
    """A few values read off the seed's table by hand, and its continuity (mod 360) across
    the row boundaries, and the seam at theta = 225 deg for 0 < phi < 90 deg."""
    assert H.left_arm_twist_deg(0, 0) == 180  # row 1
    assert H.left_arm_twist_deg(45, 45) == 180 - 45 * 0.5  # row 1
    assert H.left_arm_twist_deg(45, 135) == -180 * 0.5 + (135 - 270) * 0.5  # row 2
    assert H.left_arm_twist_deg(135, 135) == (135 - 180) * 1.5  # row 3
    assert H.left_arm_twist_deg(135, 45) == 2 * (-45) * 0.5 - 315 * 0.5  # row 4
    assert H.left_arm_twist_deg(200, 30) == (-20) * 0.0 + 360 / 3  # row 5, before the seam
    assert H.left_arm_twist_deg(250, 30) == (-70) * 0.0 - 360 / 3  # row 5, after the seam
    # On the seam itself the sgn(225 - theta) = +1 branch, i.e. the limit from below.
    assert abs(H.left_arm_twist_deg(225, 30) - H.left_arm_twist_deg(225 - 1e-9, 30)) < 1e-6
    eps = 1e-7
    for phi in np.linspace(0, 180, 37):
        for theta in (-90, 90, 180, 270):
            a = H.left_arm_twist_deg(theta - eps, phi)
            b = H.left_arm_twist_deg(theta + eps, phi)
            assert abs(_mod360(a - b)) < 1e-4, (theta, phi)
    for theta in np.linspace(-180, 180, 73):
        a = H.left_arm_twist_deg(theta, 90 - eps)
        b = H.left_arm_twist_deg(theta, 90 + eps)
        assert abs(_mod360(a - b)) < 1e-4, theta
    jump = H.left_arm_twist_deg(225 - eps, 30) - H.left_arm_twist_deg(225 + eps, 30)
    assert abs(jump - 720 * 30 / 90) < 1e-4


def test_reference_swing_is_continuous_at_the_opposite_pole():
    """The reference's convention opposite the rest direction is the limit along the
    meridian of theta (a check of helpers.py, not of diffbody)."""
    for d_rest, pole in (([0, 0, 1], math.pi), ([0, 0, -1], 0.0)):
        d_rest = np.asarray(d_rest, dtype=float)
        inward = 1e-7 if pole == 0.0 else -1e-7
        for theta in np.linspace(-math.pi, math.pi, 13):
            at = H.base_in_socket("swing", d_rest, theta, pole)
            near = H.base_in_socket("swing", d_rest, theta, pole + inward)
            np.testing.assert_allclose(at, near, atol=1e-6)
            np.testing.assert_allclose(at @ at.T, np.eye(3), atol=1e-12)
            np.testing.assert_allclose(at[:, 2], H.direction(theta, pole), atol=1e-12)


def test_mirror_and_leg_tables():
    rng = np.random.default_rng(11)
    for theta, phi in zip(rng.uniform(-360, 360, 200), rng.uniform(0, 180, 200)):
        assert H.right_arm_twist_deg(theta, phi) == -H.left_arm_twist_deg(-theta, phi)
        assert H.right_leg_twist_deg(theta, phi) == -H.left_leg_twist_deg(-theta, phi)
        # The leg table is continuous (mod 360) across phi = 90 deg and across theta = 0;
        # like the arm's, it has a seam behind the body (theta = 180 deg, phi < 90 deg).
        a, b = H.left_leg_twist_deg(theta, 90 - 1e-9), H.left_leg_twist_deg(theta, 90)
        assert abs(_mod360(a - b)) < 1e-6
        a, b = H.left_leg_twist_deg(-1e-9, phi), H.left_leg_twist_deg(1e-9, phi)
        assert abs(_mod360(a - b)) < 1e-6
