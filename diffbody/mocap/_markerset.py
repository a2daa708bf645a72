"""Marker sets at work (docs/design.md, section 7): matching a set to a trial's markers, the
markers' world positions in a pose, and a set carried to a scaled body. Reading a set file is
`diffbody.files` (`load_markerset`)."""

import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._body import Body, Pose
from .._kinematics import full_chain, place_on_segments, pose_frames, reroot, walk_links, world_base
from ..files._marker_trial import MarkerTrial
from ..files._markerset_file import MarkerSet


class MarkerWarning(UserWarning):
    """A marker set and a trial that do not name the same markers (`match_markers`)."""


# --- matching a trial -----------------------------------------------------------------------
def match_markers(markerset: MarkerSet, trial: MarkerTrial) -> tuple[MarkerSet, MarkerTrial]:
    """Both restricted to the markers they share, in the set's order.

    Set markers the trial lacks, and trial markers the set does not map, are each named
    in one `MarkerWarning` (filter it with `warnings.simplefilter("ignore", MarkerWarning)`)
    and left out. No shared marker at all is a ValueError.
    """
    in_trial = set(trial.names)
    shared = [n for n in markerset.names if n in in_trial]
    absent = [n for n in markerset.names if n not in in_trial]
    unmapped = [n for n in trial.names if n not in set(markerset.names)]
    if absent:
        warnings.warn(
            f"marker set {markerset.name!r}: {len(absent)} marker(s) not in the trial "
            f"{trial.source!r}, left out: {', '.join(absent)}",
            MarkerWarning,
            stacklevel=2,
        )
    if unmapped:
        warnings.warn(
            f"trial {trial.source!r}: {len(unmapped)} marker(s) the marker set "
            f"{markerset.name!r} does not map, ignored: {', '.join(unmapped)}",
            MarkerWarning,
            stacklevel=2,
        )
    if not shared:
        raise ValueError(
            f"match_markers: the marker set {markerset.name!r} and the trial "
            f"{trial.source!r} share no marker name (set: {', '.join(markerset.names[:5])}, "
            f"...; trial: {', '.join(trial.names[:5])}, ...)"
        )
    return markerset.select(shared), trial.select(shared)


# --- kinematics -----------------------------------------------------------------------------
def marker_positions(
    body: Body,
    R_world_base: Float[Array, "n_seg 3 3"],
    p_world_proximal: Float[Array, "n_seg 3"],
    tau: Float[Array, " n_seg"],
    markerset: MarkerSet,
) -> Float[Array, "n 3"]:
    """World positions (m) of the markers, given every segment's untwisted world frame, its
    proximal joint and its twist (from a walk: `Links.R_base`, `Links.p_proximal`)."""
    seg = np.asarray(markerset.segments, dtype=int)
    offsets = markerset.offsets
    placed = place_on_segments(body, seg, offsets, offsets[:, 2], R_world_base[seg], tau[seg])
    return p_world_proximal[seg] + placed


def world_markers(body: Body, pose: Pose, markerset: MarkerSet) -> Float[Array, "n 3"]:
    """World positions (m) of the markers of `markerset` for `body` in `pose` (the same walk
    as `diffbody.forward`; pure, un-jitted: compose under jit/vmap/grad)."""
    R_socket_base, tau = pose_frames(body, pose)
    position = jnp.asarray(pose.position, R_socket_base.dtype)
    links = walk_links(body, full_chain(body), R_socket_base, tau, world_base(position))
    links = reroot(body, links, position)
    return marker_positions(body, links.R_base, links.p_proximal, tau, markerset)


def scale_offsets(
    markerset: MarkerSet,
    body_template: Body,
    axial: Float[ArrayLike, " n_seg"],
    radial: Float[ArrayLike, " n_seg"],
) -> MarkerSet:
    """The set carried to `scale_body(body_template, axial, radial)`: each offset scales
    like a sphere origin, X and Y by its segment's radial factor, Z by its axial factor."""
    a, r = jnp.asarray(axial), jnp.asarray(radial)
    if a.shape != (body_template.n_segments,) or r.shape != a.shape:
        raise ValueError(
            f"scale_offsets: axial and radial must be ({body_template.n_segments},) per-segment "
            f"factors of body {body_template.name!r}, got {a.shape} and {r.shape}"
        )
    seg = np.asarray(markerset.segments, dtype=int)
    xyz = jnp.stack([r[seg], r[seg], a[seg]], axis=-1)
    return eqx.tree_at(lambda m: m.offsets, markerset, markerset.offsets * xyz)
