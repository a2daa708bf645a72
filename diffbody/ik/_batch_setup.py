"""A batch reach's set-up (docs/design.md, section 6, "Batches"): the arguments checked and
what the steps of `solve_reach_batch` share, prepared on the host."""

from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body, Pose
from .._device_arrays import device_array
from ..problem._constraints import is_constraint
from ..problem._targets import Target, TargetSet, resolve_targets
from ..problem._unknowns import Layout
from ..runs._batches import bucket, chunk_rows, row_sharding
from ._phases import phase_layouts, phase_targets_of, uses_limb_start
from ._plans import limb_plans
from ._reach import check_settings, constrained_targets

# Rows per compiled call of the passes over the rows that still miss (further rounds and
# starts, the trunk's phase), when fewer than half a chunk: the few rows left after the
# first round run in chunks their size, not padded to a whole chunk (one more compiled
# shape, for batches larger than this).
RETRY_ROWS = 64


def check_batch(body: Body, effectors: Sequence[str], **settings) -> None:
    """Refuse bad settings of `solve_reach_batch` (as it would) before any row is read."""
    prepare(body, effectors, np.zeros((1, len(effectors), 3)), **settings)


@dataclass(frozen=True)
class Setup:
    """What the steps of a batch solve share, checked and prepared on the host."""

    body: Body
    xyz: np.ndarray  # (n, k, 3) m
    templates: list[TargetSet]  # per phase, the targets of one row (positions replaced)
    plans: list  # per phase, its limb chain's layout, plan and padded targets, or None
    closed: list[bool]  # per phase, whether its first start is the closed-form limb start
    init: Pose
    layouts: list[Layout]  # the phases
    starts: int
    max_steps: int
    tol_position: float  # m, as given
    tols: tuple[Array, Array]  # m, rad: the solver's tolerances
    chunk: int  # rows per compiled call, a multiple of the device count
    retry_chunk: int  # rows per compiled call of a pass over fewer than half a chunk
    sharding: jax.sharding.Sharding
    progress: bool


def prepare(
    body: Body,
    effectors,
    positions,
    *,
    init,
    chunk_size,
    progress,
    devices,
    spine,
    standing,
    constraints,
    segments,
    starts,
    max_steps,
    tol_position,
) -> Setup:
    """Check the arguments (host) and prepare the solve: positions as (n, k, 3), the
    targets' template, the phases' layouts, the chunk size and the devices' sharding."""
    effectors = [effectors] if isinstance(effectors, str) else list(effectors)
    k = len(effectors)
    xyz = np.asarray(positions, dtype=float)
    if k == 1 and xyz.ndim == 2:
        xyz = xyz[:, None, :]
    if k == 0 or xyz.ndim != 3 or xyz.shape[1:] != (k, 3):
        raise ValueError(
            f"solve_reach_batch: positions must have shape (n, {k}, 3) for {k} effector(s)"
            + (" or (n, 3)" if k == 1 else "")
            + f", got {np.shape(positions)}"
        )
    check_settings(starts=starts, max_steps=max_steps, tol_position=tol_position, tol_angle=1.0)
    template, _ = resolve_targets(body, [Target.position(e, np.zeros(3)) for e in effectors])
    default_init = init is None
    init = body.rest_pose() if default_init else init
    constraints = list(constraints)
    if not all(isinstance(c, Target) and is_constraint(c) for c in constraints):
        raise TypeError(
            "solve_reach_batch: constraints must be Target.no_contact / .on_floor / .balance"
        )
    stand = standing and segments is None
    phase_targets = constrained_targets(body, template, constraints, init, stand, default_init)
    layouts = phase_layouts(
        body, phase_targets, spine=spine, free_root=False, segments=segments, stand=stand
    )
    templates = phase_targets_of(layouts, phase_targets)
    closed = [uses_limb_start(k, templates[0]) for k in range(len(layouts))]
    n = xyz.shape[0]
    devices = list(jax.local_devices() if devices is None else devices)
    # Power-of-two buckets: 17 and 32 rows run one program (a row costs little beside a call).
    chunk = chunk_rows(chunk_size, bucket(n), len(devices))
    dtype = jnp.result_type(float)
    tols = (device_array(tol_position, dtype), device_array(np.deg2rad(1.0), dtype))
    return Setup(
        body=body,
        xyz=xyz,
        templates=templates,
        plans=limb_plans(body, layouts, templates, closed),
        closed=closed,
        init=init,
        layouts=layouts,
        starts=starts,
        max_steps=max_steps,
        tol_position=tol_position,
        tols=tols,
        chunk=chunk,
        retry_chunk=chunk_rows(min(chunk, RETRY_ROWS), bucket(n), len(devices)),
        sharding=row_sharding(devices),
        progress=progress,
    )
