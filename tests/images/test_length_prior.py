"""The population prior on a joint tree's part lengths: held-out people look like draws from
it, its rows in the lifting, the lifting with it, and bad settings refused."""

import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.images._joint_tree import JointTree, default_joint_tree
from diffbody.images._length_prior import length_prior, population_lengths
from diffbody.images._lifting import LiftOptions, lift, shape_rows


@pytest.fixture(scope="module")
def tree():
    return default_joint_tree()


def _first_of_groups(tree):
    groups = np.asarray(tree.length_groups(True))
    return np.asarray([np.flatnonzero(groups == g)[0] for g in range(groups.max() + 1)])


@pytest.mark.parametrize("sex", ["male", "female"])
def test_held_out_people_look_like_draws_from_the_prior(tree, sex):
    """Fitted to half of the shipped subjects, the other half's whitened log lengths have
    mean near 0 and covariance near the identity (a Gaussian that describes people it has
    not seen), and the median person of the survey (the default body) lies near its centre."""
    from diffbody.files._data_files import data_rows

    rows = np.asarray(
        [int(r["row"]) for r in data_rows("webb/ansur2_axial_scales.csv") if r["sex"] == sex]
    )
    fit, held = rows[::2], rows[1::2]
    prior = length_prior(tree, sex, rows=fit)
    x = np.log(population_lengths(tree, sex, rows=held))[:, _first_of_groups(tree)]
    z = (x - np.asarray(prior.mean)) @ np.asarray(prior.whiten).T
    assert np.all(np.abs(z.mean(0)) < 0.15), z.mean(0)
    cov = np.cov(z, rowvar=False)
    assert np.all(np.abs(np.diag(cov) - 1) < 0.25), np.diag(cov)
    assert np.max(np.abs(cov - np.diag(np.diag(cov)))) < 0.2
    body = db.load_body(variant=f"{sex}50")
    rest = np.asarray(db.walking_motion(body, tree, 1))[0]
    median = np.log(
        np.linalg.norm(rest[list(tree.part_end)] - rest[list(tree.part_start)], axis=-1)
    )
    zm = np.asarray(prior.whiten) @ (median[_first_of_groups(tree)] - np.asarray(prior.mean))
    assert np.all(np.abs(zm) < 1.5), zm


def test_the_prior_rows(tree):
    """Border-only rows on frame 0: the whitened log lengths; with a prior, the pull toward
    the start holds only from below (Webb's lengths are lower bounds)."""
    prior = length_prior(tree, "male")
    G = prior.mean.shape[0]
    d = jnp.zeros((4, tree.n_parts, 3))
    log0 = jnp.asarray(prior.mean) + 0.05
    log_len = log0 + jnp.linspace(-0.1, 0.1, G)
    opts = LiftOptions(prior=prior)
    pull, rows = shape_rows(opts, d, log_len, log0)
    below = np.minimum(np.asarray(log_len - log0), 0.0) / opts.length_sigma
    np.testing.assert_allclose(pull[0], below, atol=1e-12)
    expected = np.asarray(prior.whiten) @ np.asarray(log_len - prior.mean)
    np.testing.assert_allclose(rows[0], expected, atol=1e-12)
    assert not np.any(np.asarray(pull[1:])) and not np.any(np.asarray(rows[1:]))
    (plain,) = shape_rows(LiftOptions(), d, log_len, log0)  # no prior: both ways
    np.testing.assert_allclose(plain[0], np.asarray(log_len - log0) / 0.05, atol=1e-12)


def test_bad_priors_are_refused(tree):
    prior = length_prior(tree, "male")
    uv, depth = np.zeros((3, tree.n_joints, 2)), np.full(3, 3.0)
    with pytest.raises(ValueError, match="symmetric=True"):
        lift(tree, uv, depth, 1000.0, options=LiftOptions(prior=prior, symmetric=False))
    small = JointTree.from_parents(["center_hip", "left_hip", "left_knee"], [-1, 0, 1])
    with pytest.raises(ValueError, match="build it for this tree"):
        lift(small, uv[:, :3], depth, 1000.0, options=LiftOptions(prior=prior))
    with pytest.raises(KeyError, match="nose"):
        length_prior(JointTree.from_parents(["center_hip", "nose"], [-1, 0]))
    with pytest.raises(ValueError, match="sex"):
        length_prior(tree, "other")
