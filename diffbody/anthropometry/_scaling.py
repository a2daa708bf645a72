"""Scaling a body's dimensions (docs/design.md, section 7): per-segment axial and radial scale
factors, as OpenSim's scale factors scale everything attached to a body.

A segment's **axial** scale multiplies its length and the Z (along-the-segment) coordinate
of everything on it: sphere origins, the centroid, the enclosure's centre. Its **radial**
scale multiplies the off-axis (X, Y) coordinates and the sphere radii. Directions, limits
and the tree stay as they are, so a scaled body loads, renders, reaches and exports like the
one it came from. Masses follow the volume, axial x radial^2, unless a total is given.

`rest_points` is the standard position's geometry in JAX, the twin of the NumPy
`rest_geometry`: no walk, since every frame there is the standard cross of axes, but one
product of a constant ancestor matrix with each segment's length x rest direction. Joints are
then linear in the lengths, so every measurement of the standard position is differentiable,
and piecewise linear, in the scale factors (docs/design.md, section 3).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._body import Body
from .._chain import on_paths
from .._device_arrays import device_array
from .._programs import compiled

# Scale groups: segments scaled together. Left and right share a factor (ANSUR II measures
# one side), the five lumbar and the twelve thoracic vertebrae each share one.
SCALE_GROUPS: dict[str, tuple[str, ...]] = {
    "pelvis": ("pelvis",),
    "hips": ("left_pelvis", "right_pelvis"),  # the hip joints' spacing
    "lumbar": ("L1", "L2", "L3", "L4", "L5"),
    "thorax": tuple(f"T{i}" for i in range(1, 13)),
    "neck": ("neck",),
    "head": ("head",),
    "clavicle": ("left_clavicle", "right_clavicle"),
    "upper_arm": ("left_upper_arm", "right_upper_arm"),
    "forearm": ("left_forearm", "right_forearm"),
    "hand": ("left_hand", "right_hand"),
    "thigh": ("left_thigh", "right_thigh"),
    "shank": ("left_shank", "right_shank"),
    "foot": ("left_foot", "right_foot"),
}
N_GROUPS = len(SCALE_GROUPS)  # scale groups, each with an axial and a radial factor


def group_index(body: Body, groups: dict[str, tuple[str, ...]] = SCALE_GROUPS) -> np.ndarray:
    """(n_seg,) the group of each segment (static); -1 for segments in no group (the whole
    body), which keep scale 1. Raises KeyError naming a group's unknown segment."""
    index = np.full(body.n_segments, -1)
    for g, names in enumerate(groups.values()):
        for name in names:
            index[body.segment_index(name)] = g
    return index


def per_segment(body: Body, group_scales: Float[ArrayLike, "*b n_group"]) -> Array:
    """Group scale factors -> (*b, n_seg) segment scale factors (1 outside every group)."""
    g = group_index(body)
    s = jnp.asarray(group_scales)
    padded = jnp.concatenate([s, jnp.ones(s.shape[:-1] + (1,), s.dtype)], axis=-1)
    return padded[..., g]  # index -1 picks the appended 1


def scale_body(
    body: Body,
    axial: Float[ArrayLike, " n_seg"],
    radial: Float[ArrayLike, " n_seg"],
    *,
    total_mass: Float[ArrayLike, ""] | None = None,
) -> Body:
    """The body with every segment's axial and radial dimensions scaled (module docstring).

    Args:
        body: the body to scale.
        axial, radial: (n_seg,) positive scale factors per segment (`per_segment` maps group
            factors to segments).
        total_mass: kg; masses are scaled by volume (axial x radial^2) and then, when this is
            given, all by one factor so that they sum to it.

    The enclosures stay enclosures: the centre's z scales axially and the radius by
    max(axial, radial), which bounds how far any point of the segment moves (they are no
    longer the smallest; `load_body` recomputes the smallest for a saved file).

    One compiled program per body structure (op by op, its dozens of small operations would
    compile a program each on a first call); inlined under a transformation.
    """
    # Arrays, never Python numbers or lists: those would be static, a program per value.
    axial, radial = _array(axial), _array(radial)
    return _scale_body_jit(body, axial, radial, None if total_mass is None else _array(total_mass))


def _array(x):
    return x if isinstance(x, (jax.Array, np.ndarray)) else device_array(x)


def _scale_body(body: Body, axial, radial, total_mass) -> Body:
    """`scale_body`, traced."""
    a = jnp.asarray(axial)
    r = jnp.asarray(radial)
    xyz = jnp.stack([r, r, a], axis=-1)  # (n_seg, 3): X and Y radial, Z axial
    # Features ride on their sphere (origin + radius * direction): they scale with it.
    seg = np.asarray(body.sphere_segment, dtype=int)
    masses = body.masses * a * r**2
    if total_mass is not None:
        masses = masses * (jnp.asarray(total_mass) / jnp.sum(masses))
    scaled = eqx.tree_at(
        lambda b: (
            b.lengths,
            b.sphere_origins,
            b.sphere_radii,
            b.centroids,
            b.masses,
            b.enclosure_z,
            b.enclosure_radii,
        ),
        body,
        (
            body.lengths * a,
            body.sphere_origins * xyz[seg],
            body.sphere_radii * r[seg],
            body.centroids * xyz,
            masses,
            body.enclosure_z * a,
            body.enclosure_radii * jnp.maximum(a, r),
        ),
    )
    return stand_on_ground(scaled)


def rest_points(body: Body) -> tuple[Array, Array]:
    """Joint positions (n_joint, 3) and sphere centres (n_sph, 3) of the standard position,
    relative to the root joint (m). Every frame is the standard cross of axes, so this is one
    matrix product: each joint is the sum of length x direction over the segments above it."""
    R = body.R_socket_rest
    steps = body.lengths[:, None] * R[:, :, 2]
    # Joint j >= 1 ends segment j - 1; joint 0 has no segment (the whole body, on every
    # path, has length 0).
    joints = jnp.asarray(on_paths(body.parent, range(-1, body.n_segments))) @ steps
    joints = joints - joints[body.root_joint]
    seg = np.asarray(body.sphere_segment, dtype=int)
    proximal = np.asarray(body.proximal_joint)[seg]
    centers = joints[proximal] + jnp.einsum("kij,kj->ki", R[seg], body.sphere_origins)
    return joints, centers


def stand_on_ground(body: Body) -> Body:
    """The body placed so that its lowest sphere touches z = 0 with the root joint above the
    world origin (as `load_body` places it)."""
    _, centers = rest_points(body)
    lowest = jnp.min(centers[:, 2] - body.sphere_radii) if body.n_spheres else 0.0
    position = jnp.zeros(3, body.lengths.dtype).at[2].set(-lowest)
    return eqx.tree_at(lambda b: b.rest_position, body, position)


def log_scaled(template: Body, log_axial: Array, log_radial: Array) -> Body:
    """The template with the group scale factors exp(log_axial), exp(log_radial) (each
    `(N_GROUPS,)`): the unknowns of the fits that scale a body by gradient. One compiled
    program, as `scale_body`."""
    return _log_scaled_jit(template, _array(log_axial), _array(log_radial))


def _log_scaled(template: Body, log_axial: Array, log_radial: Array) -> Body:
    axial = per_segment(template, jnp.exp(log_axial))
    radial = per_segment(template, jnp.exp(log_radial))
    return _scale_body(template, axial, radial, None)


def log_scaled_many(template: Body, log_axial: ArrayLike, log_radial: ArrayLike) -> Body:
    """`log_scaled` of (b, N_GROUPS) factors: the bodies as one with a leading batch axis on
    every array, in one compiled program."""
    return _log_scaled_many_jit(template, _array(log_axial), _array(log_radial))


def _log_scaled_many(template: Body, log_axial, log_radial) -> Body:
    return jax.vmap(_log_scaled, in_axes=(None, 0, 0))(template, log_axial, log_radial)


_scale_body_jit = compiled(_scale_body)
_log_scaled_jit = compiled(_log_scaled)
_log_scaled_many_jit = compiled(_log_scaled_many)
