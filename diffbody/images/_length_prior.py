"""The population prior on a joint tree's part lengths (docs/design.md, section 8): what
ANSUR II says about how a person's parts go together, for the image-sequence lifting.

The default body of each sex scaled to every ANSUR II subject of an even row of the survey
(all their measurements but weight; data/webb/ansur2_axial_scales.csv, its generator beside
it) gives each subject's part lengths: the distances between the tree's joints in the
standard position. Their logarithms' mean and covariance, over the tree's length groups
(left and right share one), are the prior: a Gaussian of the log lengths, as the body
measurements' prior (`PopulationPrior`) is. In a least-squares problem it is the rows
`whiten @ (log L - mean)`; given what the images pin down, the rest follow its conditional.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._kinematics import forward
from ..anthropometry._prior import check_sex
from ..anthropometry._scale_to import scaled_body
from ..files._body_file import load_body
from ..files._data_files import data_rows
from ._joint_tree import JointTree, observed_points

SCALES_FILE = "webb/ansur2_axial_scales.csv"


class LengthPrior(eqx.Module):
    """A Gaussian of a joint tree's log length groups (`JointTree.length_groups(True)`)."""

    mean: Float[Array, " n_groups"]  # log m
    whiten: Float[Array, "n_groups n_groups"]  # inverse Cholesky factor of the covariance


def population_lengths(tree: JointTree, sex: str, rows: np.ndarray | None = None) -> np.ndarray:
    """(n, P) m: the tree's part lengths of the default body of `sex` scaled to each subject
    of the shipped scale factors (the even rows), or to those whose row is in `rows`."""
    check_sex(sex)
    table = [r for r in data_rows(SCALES_FILE) if r["sex"] == sex]
    if rows is not None:
        wanted = set(np.asarray(rows).tolist())
        table = [r for r in table if int(r["row"]) in wanted]
    template = load_body(variant=f"{sex}50")
    groups = [k for k in table[0] if k not in ("sex", "row")]
    axial = np.asarray([[float(r[g]) for g in groups] for r in table])
    s, e = list(tree.part_start), list(tree.part_end)

    def lengths(log_axial):
        log_scales = jnp.stack([log_axial, jnp.zeros_like(log_axial)])
        body = scaled_body(template, log_scales)
        k = forward(body, body.rest_pose())
        p = observed_points(tree, body, k.joint_positions, k.feature_points)
        return jnp.linalg.norm(p[jnp.asarray(e)] - p[jnp.asarray(s)], axis=-1)

    return np.asarray(jax.jit(jax.vmap(lengths))(jax.device_put(axial)))


def group_firsts(tree: JointTree) -> np.ndarray:
    """(G,) the first part of each length group (`JointTree.length_groups(True)`): on a
    scaled body a group's parts have one length."""
    groups = np.asarray(tree.length_groups(True))
    return np.asarray([np.flatnonzero(groups == g)[0] for g in range(groups.max() + 1)])


def length_prior(tree: JointTree, sex: str = "male", rows: np.ndarray | None = None) -> LengthPrior:
    """The prior of the tree's log length groups for `sex` (module docstring); `rows`: only
    these subjects (0-based rows of the survey's file; the even ones are shipped). Every
    joint of the tree must be a joint or a feature of the default body (KeyError naming it)."""
    first = group_firsts(tree)
    n_groups = len(first)
    x = np.log(population_lengths(tree, sex, rows))[:, first]
    if len(x) <= n_groups:
        raise ValueError(
            f"length_prior: {len(x)} subjects for {n_groups} length groups; give more rows"
        )
    cov = np.cov(x, rowvar=False) + 1e-10 * np.eye(n_groups)
    whiten = np.linalg.inv(np.linalg.cholesky(cov))
    return LengthPrior(jnp.asarray(x.mean(0)), jnp.asarray(whiten))
