"""Webb's static analysis (seed 003): the formulas against closed forms, exact lengths when
the seed's conditions hold, the order dependence when condition 3 fails, bad input, the
observed skeleton, and the command line."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from diffbody.cli import main
from diffbody.files._body_file import data_file
from diffbody.images._joint_tree import (
    JointTree,
    default_joint_tree,
    hinge_limits,
    read_joint_tree,
    write_joint_tree,
)
from diffbody.images._motions import walking_motion
from diffbody.images._pinhole import camera_around, image_sequence, project, to_camera
from diffbody.images._webb import (
    FAR,
    MISSED,
    NEAR,
    perpendicular_foot,
    ray_sphere,
    true_reflections,
    webb,
)

F = 1000.0  # px


@pytest.fixture(scope="module")
def tree():
    return default_joint_tree()


# --- formulas (1) and (2) -------------------------------------------------------------------
finite = st.floats(-2.0, 2.0, allow_nan=False)


@given(finite, finite, st.floats(1.0, 5.0), finite, finite)
def test_formulas_match_closed_form(x, y, z, u, v):
    """(2): p w is the orthogonal projection of the start on the ray; (1): r is the start's
    distance from the ray, |S x w| / |w| (the closed form from the cross product)."""
    S = np.array([x, y, z])
    w = np.array([u * 300.0, v * 300.0, F])
    p, r = perpendicular_foot(jnp.asarray(S), jnp.asarray(w))
    w_hat = w / np.linalg.norm(w)
    foot = np.dot(S, w_hat) * w_hat
    np.testing.assert_allclose(float(p) * w, foot, atol=1e-12)
    np.testing.assert_allclose(
        float(r), np.linalg.norm(np.cross(S, w)) / np.linalg.norm(w), atol=1e-12
    )
    # the seed's own spelling of (1) and (2)
    pp = (u * 300.0 * x + v * 300.0 * y + F * z) / ((u * 300.0) ** 2 + (v * 300.0) ** 2 + F**2)
    rr = math.sqrt((x - pp * u * 300.0) ** 2 + (y - pp * v * 300.0) ** 2 + (z - pp * F) ** 2)
    assert float(p) == pytest.approx(pp, rel=1e-12)
    assert float(r) == pytest.approx(rr, rel=1e-9, abs=1e-12)


@given(finite, finite, st.floats(1.0, 5.0), finite, finite, st.floats(0.0, 1.0))
def test_ray_sphere_points_lie_on_both(x, y, z, u, v, extra):
    """Both reflections lie on the ray and on the sphere; near has the smaller depth; a
    sphere smaller than the start's distance from the ray is missed."""
    S = jnp.asarray([x, y, z])
    w = jnp.asarray([u * 300.0, v * 300.0, F])
    _, d = perpendicular_foot(S, w)
    radius = d + extra
    t, hit = ray_sphere(S, w, radius)
    assert bool(hit)
    for k in range(2):
        assert float(jnp.linalg.norm(t[k] * w - S)) == pytest.approx(float(radius), abs=1e-9)
    assert float(t[0]) <= float(t[1])
    _, hit = ray_sphere(S, w, 0.5 * d)
    assert bool(hit) == (float(d) == 0.0)


def test_ray_sphere_gradient_finite_at_tangency():
    S = jnp.asarray([0.3, -0.2, 3.0])
    w = jnp.asarray([0.0, 0.0, F])
    _, d = perpendicular_foot(S, w)
    g = jax.grad(lambda r: ray_sphere(S, w, r)[0][1])(d)  # exactly tangent
    assert np.isfinite(float(g))


# --- sequences that meet the seed's conditions, and one that violates condition 3 ----------
def _positions(tree: JointTree, root, directions, lengths):
    """Joints (J, 3) of the tree from the reference and unit part directions (P, 3)."""
    pos = np.zeros((tree.n_joints, 3))
    pos[tree.root] = root
    for k in range(tree.n_parts):
        pos[tree.part_end[k]] = pos[tree.part_start[k]] + lengths[k] * directions[k]
    return pos


def _conditioned(tree, male50, when):
    """A 40-frame sequence (camera frame) of the walking body in which part k is seen
    exactly perpendicular to the ray through its ending point at frame when[k] (the seed's
    condition 2): its direction d there satisfies S . d = -L (a right angle at the ending
    point), the nearest such direction to the walking one."""
    world = np.asarray(walking_motion(male50, tree, 40))
    camera = camera_around([0.0, 0.0, 1.0], 3.0, 25.0, 1.2, F)
    joints = np.array(to_camera(camera, world))
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    vec = joints[:, e] - joints[:, s]
    lengths = np.linalg.norm(vec[0], axis=-1)
    dirs = vec / np.linalg.norm(vec, axis=-1, keepdims=True)
    for k in range(tree.n_parts):  # top-down
        t = when[k]
        S = _positions(tree, joints[t, tree.root], dirs[t], lengths)[s[k]]
        S_hat = S / np.linalg.norm(S)
        a = -lengths[k] / np.linalg.norm(S)
        u = dirs[t, k] - np.dot(dirs[t, k], S_hat) * S_hat
        dirs[t, k] = a * S_hat + math.sqrt(1 - a * a) * u / np.linalg.norm(u)
        joints[t] = _positions(tree, joints[t, tree.root], dirs[t], lengths)
    return joints, lengths


def _levels(tree):
    depth = {}
    for level, parts in enumerate(tree.levels):
        for k in parts:
            depth[k] = level
    return depth


def test_exact_lengths_when_conditions_hold(tree, male50):
    """Conditions 1-3 (true reflections; every part once perpendicular to its ray; a part
    after the parts above it): the lengths are exact, and so is every joint once every
    part has been seen so."""
    depth = _levels(tree)
    when = [3 + 5 * depth[k] + k % 3 for k in range(tree.n_parts)]
    joints, lengths = _conditioned(tree, male50, when)
    uv = project(joints, F)
    out = webb(tree, uv, joints[:, tree.root, 2], F, true_reflections(tree, joints))
    np.testing.assert_array_less(np.abs(np.asarray(out.lengths) / lengths - 1), 1e-6)
    after = max(when) + 1
    np.testing.assert_allclose(np.asarray(out.joints[after:]), joints[after:], atol=1e-6)
    # the seed's idea: bounds only rise, except when a part above changes (reset)
    codes = np.asarray(out.reflections)
    assert np.all(codes[0] == MISSED)  # the first frame: every bound starts at zero
    assert set(np.unique(codes)) <= {NEAR, FAR, MISSED}
    assert bool(jnp.all(out.in_front))


def test_order_dependence_when_condition_3_fails(tree, male50):
    """The left shank seen perpendicular before the left thigh: the thigh's later change
    resets the shank's bound, which never recovers (seed 003, III B and the proof)."""
    depth = _levels(tree)
    when = [3 + 5 * depth[k] + k % 3 for k in range(tree.n_parts)]
    thigh = tree.part_names.index("left_hip->left_knee")
    shank = tree.part_names.index("left_knee->left_ankle")
    when[thigh], when[shank] = 20, 10
    joints, lengths = _conditioned(tree, male50, when)
    uv = project(joints, F)
    out = webb(tree, uv, joints[:, tree.root, 2], F, true_reflections(tree, joints))
    rel = np.asarray(out.lengths) / lengths - 1
    assert rel[shank] < -1e-3  # a lower bound that stays short
    others = [k for k in range(tree.n_parts) if k != shank]
    np.testing.assert_array_less(np.abs(rel[others]), 1e-6)
    bounds = np.asarray(out.bounds)
    assert bounds[20, shank] < bounds[19, shank]  # reset by the thigh's change


def test_batch_equals_loop(tree, male50):
    world = walking_motion(male50, tree, 6)
    seqs = [
        image_sequence(
            tree, camera_around([0, 0, 1], 3.0, az, 1.2, F), world, 1.0, jax.random.PRNGKey(i)
        )
        for i, az in enumerate((0.0, 120.0))
    ]
    uv = np.stack([np.asarray(s.uv) for s in seqs])
    depth = np.stack([np.asarray(s.root_depth) for s in seqs])
    refl = np.stack([np.asarray(true_reflections(tree, s.joints)) for s in seqs])
    batch = webb(tree, uv, depth, F, refl)
    for i in range(2):
        one = webb(tree, uv[i], depth[i], F, refl[i])
        np.testing.assert_allclose(np.asarray(batch.joints[i]), np.asarray(one.joints), atol=1e-12)
        np.testing.assert_array_equal(np.asarray(batch.reflections[i]), np.asarray(one.reflections))


def test_lengths_gradient_matches_finite_differences(tree, male50):
    """d lengths / d image points through the scan: jacfwd = jacrev = central differences
    (the bounds are maxima over frames, differentiable where the maximising frame is
    unique)."""
    from diffbody.images._webb import webb_kernel

    world = walking_motion(male50, tree, 6)
    seq = image_sequence(tree, camera_around([0, 0, 1], 3.0, 30.0, 1.2, F), world)
    refl = true_reflections(tree, seq.joints)

    def f(uv):
        return webb_kernel(tree, uv, seq.root_depth, jnp.asarray(F), refl).lengths

    uv = jnp.asarray(seq.uv)
    jf = jax.jit(jax.jacfwd(f))(uv)
    jr = jax.jit(jax.jacrev(f))(uv)
    np.testing.assert_allclose(jf, jr, atol=1e-10)
    rng = np.random.default_rng(0)
    direction = jnp.asarray(rng.normal(size=uv.shape))
    h = 1e-6  # px: formula (1) curves strongly; the central difference's error is O(h^2)
    fd = (f(uv + h * direction) - f(uv - h * direction)) / (2 * h)
    np.testing.assert_allclose(jnp.tensordot(jf, direction, axes=3), fd, atol=1e-9)


# --- bad input ------------------------------------------------------------------------------
def test_point_behind_camera_is_refused():
    with pytest.raises(ValueError, match=r"point \(1,\) lies behind the camera"):
        project(np.array([[0.0, 0.0, 3.0], [0.1, 0.0, -0.5]]), F)
    with pytest.raises(Exception, match="behind the camera"):
        jax.jit(project)(jnp.array([[0.0, 0.0, -3.0]]), jnp.asarray(F)).block_until_ready()


def test_bad_depth_and_focal_are_refused(tree):
    uv = np.zeros((4, tree.n_joints, 2))
    refl = np.zeros((4, tree.n_parts), int)
    depth = np.array([3.0, 3.0, -1.0, 3.0])
    with pytest.raises(
        ValueError, match=r"reference depth of frame 2 is -1; it must be a finite number > 0 m"
    ):
        webb(tree, uv, depth, F, refl)
    with pytest.raises(ValueError, match="focal length must be a finite number > 0"):
        webb(tree, uv, np.full(4, 3.0), 0.0, refl)
    with pytest.raises(ValueError, match="reflections must be 0 \\(near\\) or 1 \\(far\\)"):
        webb(tree, uv, np.full(4, 3.0), F, refl + 2)
    with pytest.raises(ValueError, match="image points must have shape"):
        webb(tree, uv[:, :3], np.full(4, 3.0), F, refl)
    bad = uv.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"image point of joint 'left_knee' in frame 1 is nan"):
        webb(tree, bad, np.full(4, 3.0), F, refl)


def test_depth_checked_inside_jit(tree):
    from diffbody.images._webb import _webb_jit

    uv = jnp.zeros((3, tree.n_joints, 2))
    with pytest.raises(Exception, match="reference depth must be > 0"):
        _webb_jit(
            tree,
            uv,
            jnp.asarray([3.0, 0.0, 3.0]),
            jnp.asarray(F),
            jnp.zeros((3, tree.n_parts), jnp.int32),
        )


def test_tree_with_cycle_is_refused(tmp_path):
    with pytest.raises(ValueError, match="cycle .*b -> c -> b"):
        JointTree.from_parents(["a", "b", "c"], [-1, 2, 1])
    with pytest.raises(ValueError, match="exactly one joint must have no parent"):
        JointTree.from_parents(["a", "b"], [-1, -1])
    with pytest.raises(ValueError, match="'b' is given twice"):
        JointTree.from_parents(["a", "b", "b"], [-1, 0, 0])
    path = tmp_path / "tree.json"
    path.write_text(
        json.dumps(
            {
                "joints": [
                    {"name": "pelvis", "parent": None},
                    {"name": "knee", "parent": "ankle"},
                    {"name": "ankle", "parent": "knee"},
                ]
            }
        )
    )
    with pytest.raises(
        ValueError, match=r"tree.json: the parents form a cycle \(knee -> ankle -> knee\)"
    ):
        read_joint_tree(path)
    path.write_text(
        json.dumps(
            {"joints": [{"name": "pelvis", "parent": None}, {"name": "knee", "parent": "hip"}]}
        )
    )
    with pytest.raises(ValueError, match="unknown parent joint .*'hip'"):
        read_joint_tree(path)
    path.write_text('{"joints": [{"name": "pelvis"}]}')
    with pytest.raises(
        ValueError, match=r"joints\[0\]: expected exactly the fields 'name' and 'parent'"
    ):
        read_joint_tree(path)


# --- the observed skeleton --------------------------------------------------------------------
def test_default_tree_and_file_round_trip(tree, male50, tmp_path):
    assert tree.n_joints == 15 and tree.n_parts == 14
    assert tree.names[tree.root] == "center_hip"
    for k, above in enumerate(tree.part_parent):  # parts come after the parts above them
        assert above < k
    groups = tree.length_groups(True)
    left = tree.part_names.index("left_knee->left_ankle")
    right = tree.part_names.index("right_knee->right_ankle")
    assert groups[left] == groups[right] and len(set(groups)) == 8
    assert len(set(tree.length_groups(False))) == 14
    limits = {tree.part_names[k]: math.degrees(a) for k, _, a in hinge_limits(tree, male50)}
    assert limits == pytest.approx(
        {
            "left_knee->left_ankle": 130.0,
            "right_knee->right_ankle": 130.0,
            "left_elbow->left_wrist": 150.0,
            "right_elbow->right_wrist": 150.0,
        }
    )
    write_joint_tree(tree, tmp_path / "t.json")
    assert read_joint_tree(tmp_path / "t.json") == tree
    assert read_joint_tree(data_file("webb/example_skeleton.json")) == tree


# --- the command line -------------------------------------------------------------------------
def test_command_line(tmp_path, capsys):
    """The example sequence (60 frames of the walking body, 1 px noise): lengths JSON with
    every part, joints for every frame, reflections, and a picture."""
    out, png = tmp_path / "lengths.json", tmp_path / "skeleton.png"
    code = main(
        [
            "webb",
            str(data_file("webb/example_points.csv")),
            "--focal",
            "1000",
            "--root-depth",
            str(data_file("webb/example_depth.csv")),
            "--out",
            str(out),
            "--png",
            str(png),
        ]
    )
    assert code == 0
    doc = json.loads(out.read_text())
    tree = default_joint_tree()
    assert list(doc["lengths_m"]) == list(tree.part_names)
    assert np.asarray(doc["joints_m"]).shape == (60, 15, 3)
    assert np.asarray(doc["reflections"]).shape == (60, 14)
    assert doc["status"] in ("converged", "not_converged")
    thigh = doc["lengths_m"]["left_hip->left_knee"]
    assert thigh == pytest.approx(0.408, rel=0.03)  # the male50 thigh
    assert png.stat().st_size > 10_000
    assert "refinement:" in capsys.readouterr().out


def test_command_line_bad_points(tmp_path, capsys):
    """Through the command's entry point: each bad file is one line naming the file, the
    row and the column, and exit status 2."""
    points = tmp_path / "p.csv"
    points.write_text("center_hip.u,center_hip.v\n1,2\n")
    depth = tmp_path / "d.csv"
    depth.write_text("3\n")
    argv = ["webb", str(points), "--focal", "1000", "--root-depth", str(depth)]

    def error() -> str:
        assert main(argv) == 2
        return capsys.readouterr().err

    assert "p.csv: row 1: no column 'left_hip.u'" in error()
    names = default_joint_tree().names
    header = ",".join(f"{n}.{c}" for n in names for c in "uv")
    row = ",".join(["1"] * 30)
    points.write_text(f"{header}\n{row}\n{row.replace('1', 'x', 1)}\n")
    assert "p.csv: row 3, column 1: not a number: 'x'" in error()
    points.write_text(f"{header}\n{row}\n{row}\n{row}\n")
    depth.write_text("depth\n3\n0\n3\n")
    assert "d.csv: row 3, column 1: depth '0' must be a finite number > 0" in error()
    with pytest.raises(SystemExit):
        main(["webb", str(points), "--focal", "-5", "--root-depth", str(depth)])
