"""Registration from the motion as well as the static trial (`scale_and_register(motion=)`;
docs/design.md, section 7, "Registration from the motion").

A static trial shows the markers in one posture. Where that posture differs from how the
subject moves, the registration learns the static posture instead of the body: the shipped
T-pose holds the acromia 342 mm apart against 419 mm while walking, and a static fit alone
shortens the clavicles to match. AddBiomechanics (Werling et al. 2023) fits the scale factors
and the markers' offsets over frames of the motion too; so does diffbody, as one weighted
least-squares problem: the static fit's rows (`_static_fit`) and, for each of k frames
spread evenly over the motion (`sample_frames`), its markers' robust rows (`robust_rows`, at
the static fit's `marker_scale`) and a weak `PULL` toward its start, with the frames'
postures unknowns beside the static one's. The frames start from a fit of them on the static
registration alone (`fit_motion`); the scale factors and offsets start from it too.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..files._marker_trial import MarkerTrial
from ..files._markerset_file import MarkerSet
from ..problem._problem import Problem
from ._marker_layout import MocapLayout
from ._marker_points import tree_markers
from ._mocap_solver import MIN_MARKERS, PULL, robust_rows

# Frames of the motion the registration also fits by default: on the shipped walk, 4 frames
# bring the walk's mean marker RMS from 18.7 to 8.3 mm, 8 to 7.3 mm, 16 to 6.6 mm
# (docs/guide.md, "Posture fitting from motion capture"); each frame adds its posture's
# unknowns to the one solve.
MOTION_FRAMES = 8


class Frames(eqx.Module):
    """The motion's frames in the registration: their postures' problems (batched over the
    k frames, each built on the template from the frame's start), measured markers (k, n, 3)
    m, 0 where missing, sqrt(weight) / `MARKER_SD` (k, n), 0 where missing, and the robust
    loss's scale (m)."""

    problem: Problem
    target: Float[Array, "k n 3"]
    sqrt_w: Float[Array, "k n"]
    scale: Float[Array, ""]

    def markers(self, lay: MocapLayout, lengths: Array, offsets: Array, X: Array) -> Array:
        """(k, n, 3) m: the model's markers of each frame, for segment `lengths`, marker
        `offsets` (n, 3) and the frames' free vectors X (k, n_free)."""
        return jax.vmap(lambda problem, x: tree_markers(lay, problem, lengths, offsets, x))(
            self.problem, X
        )

    def rows(self, lay: MocapLayout, lengths: Array, offsets: Array, X: Array) -> Array:
        """The frames' robust marker rows and pulls (`markers`' arguments): standard
        scores."""
        d = self.markers(lay, lengths, offsets, X) - self.target
        rows = jax.vmap(robust_rows, in_axes=(0, 0, None))(
            self.sqrt_w[..., None] * d, jnp.sum(d * d, axis=-1), self.scale
        )
        return jnp.concatenate([rows.ravel(), PULL * (X - self.problem.x0).ravel()])

    def errors(self, lay: MocapLayout, lengths: Array, offsets: Array, X: Array) -> Array:
        """(k, n) m: each marker's distance from its measurement, NaN where missing."""
        p = self.markers(lay, lengths, offsets, X)
        return jnp.where(self.sqrt_w > 0, jnp.linalg.norm(p - self.target, axis=-1), jnp.nan)


def motion_frame_count(k) -> int:
    """`scale_and_register`'s motion_frames, checked: an integer >= 0."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
        raise ValueError(
            f"scale_and_register: motion_frames must be an integer >= 0 (0: the static trial "
            f"alone), got {k!r}"
        )
    return int(k)


def sample_frames(
    markerset: MarkerSet, motion: MarkerTrial | list[MarkerTrial], k: int
) -> tuple[MarkerTrial, tuple[tuple[int, int], ...]]:
    """k frames spread evenly over the frames of the motion trials (one trial or a list)
    that see at least `MIN_MARKERS` of the set's markers (all of them when fewer), as one
    trial in the set's marker order: NaN where a trial lacks a marker or the marker is dead
    (`MarkerTrial.dead`); and each frame's (trial, frame) index. Raises ValueError when no
    frame qualifies, naming the files."""
    trials = _trials(motion)
    blocks, where = [], []
    for i, trial in enumerate(trials):
        index = {name: j for j, name in enumerate(trial.names)}
        dead = trial.dead()
        block = np.full((trial.n_frames, len(markerset.names), 3), np.nan)
        for j, name in enumerate(markerset.names):
            if name in index and name not in dead:
                block[:, j] = trial.positions[:, index[name]]
        seen = np.all(np.isfinite(block), axis=-1).sum(axis=1) >= MIN_MARKERS
        blocks.append(block[seen])
        where += [(i, int(f)) for f in np.flatnonzero(seen)]
    if not where:
        raise ValueError(
            f"scale_and_register: no frame of the motion "
            f"({', '.join(repr(t.source) for t in trials)}) sees {MIN_MARKERS} markers of the "
            f"set {markerset.name!r}; give another trial, or motion_frames=0 (the static trial "
            "alone)"
        )
    pick = np.unique(np.linspace(0, len(where) - 1, min(k, len(where))).round().astype(int))
    positions = np.concatenate(blocks)[pick]
    rate = trials[0].rate
    sampled = MarkerTrial(
        names=markerset.names,
        times=np.arange(len(pick)) / rate,
        positions=positions,
        rate=rate,
        source=", ".join(t.source for t in trials) + f" ({len(pick)} frames)",
    )
    return sampled, tuple(where[p] for p in pick)


def motion_markers(markerset: MarkerSet, motion: MarkerTrial | list[MarkerTrial]) -> MarkerSet:
    """The set restricted to the markers the motion's trials carry, in the set's order: the
    set `fit_motion` fits the motion with (`match_markers`), so that the registration's fit
    of its frames reuses that compiled fit."""
    names = {n for trial in _trials(motion) for n in trial.names}
    return markerset.select([n for n in markerset.names if n in names])


def _trials(motion) -> list[MarkerTrial]:
    """The motion as a list of trials; TypeError for anything else."""
    trials = [motion] if isinstance(motion, MarkerTrial) else list(motion)
    if not trials or not all(isinstance(t, MarkerTrial) for t in trials):
        raise TypeError(
            "scale_and_register: motion must be a MarkerTrial (read_markers) or a list of "
            f"them, got {motion!r}"
        )
    return trials
