"""Reach targets (docs/design.md, section 6): what the user asks for, checked on the host and turned
into index arrays for the solver."""

import math
from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._body import Body, Pose
from .._device_arrays import device_array
from .._kinematics import forward
from .._programs import is_traced
from ..contact._environment import Environment
from ..contact._support import sole_spheres
from ._constraints import Constraints

COG = "center_of_gravity"


def _check_weight(where: str, weight) -> float:
    if isinstance(weight, jax.core.Tracer):
        raise TypeError(f"{where}: weight must be a plain number, not a traced value")
    w = float(weight)
    if not (math.isfinite(w) and w >= 0.0):
        raise ValueError(f"{where}: weight must be a finite number >= 0, got {weight!r}")
    return w


def _unit(where: str, name: str, v) -> np.ndarray:
    a = np.asarray(v, float)
    if a.shape != (3,):
        raise ValueError(f"{where}: {name} must be 3 numbers, got shape {a.shape}")
    n = float(np.linalg.norm(a))
    if not (math.isfinite(n) and n > 1e-12):
        raise ValueError(f"{where}: {name} must be a finite, non-zero vector, got {a.tolist()}")
    return a / n


@dataclass(frozen=True)
class Target:
    """One reach target; build it with the class methods. A host-side description: names
    are resolved into indices by `solve_reach`."""

    kind: str  # "point", "axis", or a constraint: "no_contact", "on_floor", "balance"
    name: str  # "left_hand.palm", "left_wrist", "center_of_gravity", a segment for axes
    value: np.ndarray | Array  # (3,) position (m) or unit direction; traced under jax.grad
    axis: np.ndarray | None = None  # (3,) unit axis in the segment's twisted frame, for "axis"
    weight: float = 1.0
    # Constraints (docs/design.md, section 10):
    segments: tuple[str, ...] | None = None  # the segments it holds (None: all; on_floor: the feet)
    environment: Environment | None = None  # no_contact: shapes not to enter
    margin: float = 0.0  # m, no_contact: clearance; balance: inside the polygon's edge
    height: float = 0.0  # m, on_floor: the floor z = height
    self_contact: bool = True  # no_contact: the segments keep out of each other too

    @classmethod
    def position(
        cls, name: str, xyz: ArrayLike | Sequence[float | int], weight: float = 1.0
    ) -> "Target":
        """Put a joint ("left_wrist"), a feature ("left_hand.palm") or "center_of_gravity"
        at `xyz` (m, world). `weight` is a finite number >= 0."""
        value = xyz if isinstance(xyz, jax.Array) else np.asarray(xyz, float)
        return cls("point", name, value, None, _check_weight(f"target {name!r}", weight))

    @classmethod
    def axis_direction(
        cls,
        segment: str,
        axis: ArrayLike | Sequence[float | int],
        direction: ArrayLike | Sequence[float | int],
        weight: float = 1.0,
    ) -> "Target":
        """Turn `axis` (in the segment's twisted frame, e.g. the palm normal (0, 1, 0) of the
        left hand) to point along `direction` (world). Both non-zero; they are normalised."""
        where = f"axis target {segment!r}"
        a, d = _unit(where, "axis", axis), _unit(where, "direction", direction)
        return cls("axis", segment, d, a, _check_weight(where, weight))

    @classmethod
    def frame(cls, segment: str, R_world_segment: ArrayLike, weight: float = 1.0) -> list["Target"]:
        """A full orientation: the segment's X and Z axes along the columns of R."""
        R = np.asarray(R_world_segment, float)
        return [
            cls.axis_direction(segment, e, R[:, k], weight)
            for k, e in ((0, [1, 0, 0]), (2, [0, 0, 1]))
        ]

    @classmethod
    def no_contact(
        cls,
        segments: Sequence[str] | None = None,
        environment: Environment | None = None,
        margin: float = 0.0,
        self_contact: bool = True,
    ) -> "Target":
        """A constraint: these segments (all when None) enter no other segment of the body
        (unless `self_contact` is False) and no shape of `environment`, keeping `margin`
        (m) clear. A pair's rest overlap counts as its zero (`diffbody.contact`)."""
        _check_margin("no_contact", margin)
        if environment is not None and not isinstance(environment, Environment):
            raise TypeError("Target.no_contact: environment must be a diffbody.Environment")
        names = None if segments is None else _names("no_contact", segments)
        return cls(
            "no_contact",
            "no_contact",
            np.zeros(3),
            None,
            1.0,
            names,
            environment,
            float(margin),
            0.0,
            bool(self_contact),
        )

    @classmethod
    def on_floor(cls, segments: Sequence[str] | None = None, height: float = 0.0) -> "Target":
        """A constraint: these segments' sole spheres (the lowest in the standard
        position) touch the floor z = `height` (m) and do not slide from where the start
        pose has them. None: the body's feet (`Body.feet`: "left_foot", "right_foot")."""
        if not np.isfinite(float(height)):
            raise ValueError(f"Target.on_floor: height must be finite, got {height!r}")
        names = None if segments is None else _names("on_floor", segments)
        return cls("on_floor", "on_floor", np.zeros(3), None, 1.0, names, None, 0.0, float(height))

    @classmethod
    def balance(cls, margin: float = 0.02) -> "Target":
        """A constraint: the centre of gravity's ground projection stays inside the support
        polygon of the sole spheres of the `on_floor` targets, `margin` (m) inside its
        edges."""
        _check_margin("balance", margin)
        return cls("balance", "balance", np.zeros(3), None, 1.0, None, None, float(margin))


def _check_margin(where: str, margin) -> None:
    if not (np.isfinite(float(margin)) and float(margin) >= 0):
        raise ValueError(f"Target.{where}: margin must be a finite number >= 0 (m), got {margin!r}")


def _names(where: str, segments) -> tuple[str, ...]:
    names = (segments,) if isinstance(segments, str) else tuple(segments)
    if not names or not all(isinstance(n, str) for n in names):
        raise ValueError(f"Target.{where}: segments must be segment names, got {segments!r}")
    return names


class TargetSet(eqx.Module):
    """Targets as arrays (one problem; batch them with a leading axis)."""

    # The effectors are structure (they decide what a solve walks): static, never traced.
    point_index: tuple[int, ...] = eqx.field(static=True)  # into [joints, features, COG]
    point_xyz: Float[Array, "n_p 3"]  # m
    point_weight: Float[Array, " n_p"]
    axis_segment: tuple[int, ...] = eqx.field(static=True)
    axis_local: Float[Array, "n_a 3"]  # unit, segment's twisted frame
    axis_direction: Float[Array, "n_a 3"]  # unit, world
    axis_weight: Float[Array, " n_a"]
    constraints: Constraints | None = None


def point_index(body: Body, name: str) -> int:
    """Index of an effector into [joints, features, center of gravity]."""
    n_j, n_f = body.n_joints, len(body.feature_names)
    if name == COG:
        return n_j + n_f
    if "." in name:
        return n_j + body.feature_index(name)
    if name in body.joint_names:
        return body.joint_index(name)
    raise KeyError(
        f"unknown effector {name!r}: use a joint ({', '.join(body.joint_names[1:])}), "
        f"a feature ({', '.join(body.feature_names)}) or {COG!r}"
    )


def flatten_targets(targets: Sequence[Target | list[Target]]) -> list[Target]:
    """The targets with `Target.frame`'s lists spliced in; checks each is a Target."""
    flat: list[Target] = []
    for t in targets:
        for u in t if isinstance(t, list) else [t]:
            if not isinstance(u, Target):
                raise TypeError(
                    f"solve_reach: targets must be diffbody.Target objects, got {type(u).__name__}"
                )
            flat.append(u)
    if not flat:
        raise ValueError("solve_reach: no targets given")
    return flat


def resolve_targets(body: Body, targets: Sequence[Target]) -> tuple[TargetSet, list[int]]:
    """Names to indices (host side). Returns the arrays and the order the targets take in
    them (points first, then axes)."""
    points = [t for t in targets if t.kind == "point"]
    axes = [t for t in targets if t.kind == "axis"]
    for t in targets:
        if np.shape(t.value) != (3,):
            raise ValueError(
                f"target {t.name!r}: expected 3 numbers, got shape {np.shape(t.value)}"
            )
    order = [i for i, t in enumerate(targets) if t.kind == "point"]
    order += [i for i, t in enumerate(targets) if t.kind == "axis"]
    ts = TargetSet(
        point_index=tuple(point_index(body, t.name) for t in points),
        point_xyz=_stacked([t.value for t in points], (-1, 3)),
        point_weight=_stacked([t.weight for t in points], (-1,)),
        axis_segment=tuple(body.segment_index(t.name) for t in axes),
        axis_local=_stacked([t.axis for t in axes], (-1, 3)),
        axis_direction=_stacked([t.value for t in axes], (-1, 3)),
        axis_weight=_stacked([t.weight for t in axes], (-1,)),
    )
    return ts, order


def _stacked(values: list, shape: tuple[int, ...]) -> Array:
    """The values as one array of JAX's default float type: built in NumPy and put on the
    device (no program compiled), or stacked in JAX when one is traced (under jit, grad)."""
    if any(isinstance(v, jax.core.Tracer) for v in values):
        return jnp.stack([jnp.asarray(v) for v in values]).reshape(shape)
    return device_array(np.reshape(np.asarray(values, dtype=jnp.result_type(float)), shape))


def mask_invalid(targets: TargetSet) -> tuple[TargetSet, Array, Array]:
    """Non-finite targets take no part (weight 0, a harmless value); returns the masked set
    and the validity of the points and axes."""
    ok_p = jnp.all(jnp.isfinite(targets.point_xyz), axis=-1)
    ok_a = jnp.all(jnp.isfinite(targets.axis_direction), axis=-1)
    safe = eqx.tree_at(
        lambda t: (t.point_xyz, t.point_weight, t.axis_direction, t.axis_weight),
        targets,
        (
            jnp.where(ok_p[:, None], targets.point_xyz, 0.0),
            jnp.where(ok_p, targets.point_weight, 0.0),
            jnp.where(ok_a[:, None], targets.axis_direction, jnp.array([0.0, 0.0, 1.0])),
            jnp.where(ok_a, targets.axis_weight, 0.0),
        ),
    )
    return safe, ok_p, ok_a


def _floor(body: Body, soles: Array | np.ndarray, init: Pose) -> Array | float:
    """The lowest point of the sole spheres in `init` (m). With concrete inputs, from the
    compiled `forward` that every pose of the body structure shares and the rest in NumPy
    (docs/design.md, section 9, "Host set-up")."""
    k = forward(body, init)
    if is_traced(body, init):
        return jnp.min(k.sphere_centers[soles, 2] - k.sphere_radii[soles])
    centers, radii = np.asarray(k.sphere_centers), np.asarray(k.sphere_radii)
    return float(np.min(centers[soles, 2] - radii[soles]))


_floor_jit = eqx.filter_jit(_floor)  # traced: one program, not op by op under jax.grad


def standing(body: Body, init: Pose, height: float | None = None) -> list:
    """The targets of a standing body: the feet planted where they are in `init` (on the
    floor at the lowest of their sole spheres), the centre of gravity over them (2 cm
    inside), the floor not entered. Empty for a body with fewer than two feet (`Body.feet`)."""
    feet = [body.segment_names[s] for s in body.feet]
    if len(feet) < 2:
        return []
    if height is None:
        soles = sole_spheres(body, feet)
        height = (_floor_jit if is_traced(body, init) else _floor)(body, soles, init)
    return [
        Target.on_floor(feet, height=height),
        Target.balance(),
        Target.no_contact(environment=Environment.floor(height), self_contact=False),
    ]
