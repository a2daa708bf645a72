"""Self-contact against MuJoCo: the body exported with the segment pairs diffbody never
checks excluded (`export_mjcf(exclude=...)`), MuJoCo's `mj_collision` on poses without twist
(where the exported spheres sit exactly where `forward` puts them) finds exactly the sphere
pairs that `sphere_distances` over `sphere_pairs` finds interpenetrating, at the same depths.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from limb_poses import random_limb_angles

import diffbody as db
from diffbody.contact import sphere_distances, sphere_pairs
from diffbody.contact._pairs import excluded_segment_pairs

mujoco = pytest.importorskip("mujoco")

N_RANDOM = 6  # random poses within the swing limits, twist 0, beside the standard position
DEPTH_TOL = 1e-12  # m, float64 (the two agree to ~3e-16)
# Pairs closer to touching than this may fall on either side in either code (the thighs'
# top spheres are centred on the hip joints and touch in every pose).
BAND = 1e-9  # m
CONTACTS = 4000  # room for every contact of a pose (MuJoCo's arena)


@pytest.fixture(scope="module")
def model(male50, tmp_path_factory):
    names = male50.segment_names
    exclude = [(names[a], names[b]) for a, b in excluded_segment_pairs(male50)]
    path = db.export_mjcf(male50, tmp_path_factory.mktemp("mjcf") / "male50.xml", exclude)
    spec = mujoco.MjSpec.from_file(str(path))
    spec.nconmax = CONTACTS
    return spec.compile()


@pytest.fixture(scope="module")
def poses(male50):
    """The standard position and random swings within the limits, every twist tau = 0."""
    rng = np.random.default_rng(11)
    angles = np.array(random_limb_angles(male50, male50.segment_names, rng, N_RANDOM))
    angles[..., 2] = 0.0
    rest = male50.rest_pose()
    assert np.all(np.asarray(rest.angles[:, 2]) == 0.0)
    return [rest] + [db.Pose(rest.position, jnp.asarray(a)) for a in angles]


def _sphere_of_geom(model) -> np.ndarray:
    """Per geom, the index of its sphere in the body (geoms are `{seg}_sphere_{k}`)."""
    return np.asarray([int(model.geom(g).name.rsplit("_", 1)[1]) for g in range(model.ngeom)])


def _mujoco_contacts(model, qpos) -> dict[tuple[int, int], float]:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    assert data.warning[mujoco.mjtWarning.mjWARN_CONTACTFULL].number == 0
    sphere = _sphere_of_geom(model)
    out = {}
    for c in data.contact[: data.ncon] if data.ncon else []:
        assert model.geom_type[c.geom1] == model.geom_type[c.geom2] == mujoco.mjtGeom.mjGEOM_SPHERE
        i, j = sorted((int(sphere[c.geom1]), int(sphere[c.geom2])))
        assert (i, j) not in out
        out[(i, j)] = float(c.dist)
    return out


def test_mujoco_filters_no_pair_that_diffbody_checks(male50, model):
    """MuJoCo drops a body's own geoms, excluded pairs and parent and child (welded bodies
    count as one: here every body has its own hinges); diffbody checks none of those."""
    names = male50.segment_names
    assert list(model.body_weldid) == list(range(model.nbody))
    assert int(model.opt.disableflags) & int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT) == 0
    excluded = {
        tuple(sorted((model.body(b1).name, model.body(b2).name)))
        for b1, b2 in (divmod(int(x), 1 << 16) for x in model.exclude_signature)
    }
    assert excluded == {
        tuple(sorted((names[a], names[b]))) for a, b in excluded_segment_pairs(male50)
    }
    pairs = sphere_pairs(male50)
    for a, b in pairs.segments:
        assert tuple(sorted((names[a], names[b]))) not in excluded
        ids = model.body(names[a]).id, model.body(names[b]).id
        assert model.body_parentid[ids[0]] != ids[1] and model.body_parentid[ids[1]] != ids[0]
    assert np.all(model.geom_margin == 0) and np.all(model.geom_gap == 0)
    assert np.all(model.geom_contype == 1) and np.all(model.geom_conaffinity == 1)


def test_mujoco_finds_the_same_interpenetrating_pairs_at_the_same_depths(male50, model, poses):
    pairs = sphere_pairs(male50)
    i, j = jnp.asarray(pairs.i), jnp.asarray(pairs.j)

    @jax.jit
    def distances(pose):
        fk = db.forward(male50, pose)
        return sphere_distances(fk.sphere_centers, fk.sphere_radii, i, j)

    qpos = db.mujoco_qpos(male50, jax.tree.map(lambda *x: jnp.stack(x), *poses))
    seen = 0
    for pose, q in zip(poses, qpos):
        ours = dict(zip(zip(pairs.i.tolist(), pairs.j.tolist()), np.asarray(distances(pose))))
        theirs = _mujoco_contacts(model, q)
        # Every MuJoCo contact is one of our pairs, at the same depth...
        for key, dist in theirs.items():
            assert key in ours, key
            assert ours[key] == pytest.approx(dist, abs=DEPTH_TOL), key
        # ...and every pair of ours that interpenetrates is one of MuJoCo's contacts.
        missed = [k for k, d in ours.items() if d < -BAND and k not in theirs]
        assert not missed, missed[:5]
        assert all(ours[k] < BAND for k in theirs)
        seen += len(theirs)
    assert seen > 100 * len(poses)  # the comparison is not empty: the rest overlaps alone


def test_export_checks_the_pairs_to_exclude(male50, tmp_path):
    path = tmp_path / "body.xml"
    with pytest.raises(KeyError, match="left_hnd"):
        db.export_mjcf(male50, path, [("left_hnd", "pelvis")])
    with pytest.raises(ValueError, match="two different segments"):
        db.export_mjcf(male50, path, [("pelvis", "pelvis")])
