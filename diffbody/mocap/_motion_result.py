"""What `fit_motion` returns (`MotionFit`; docs/design.md, section 7): per frame the pose,
the model's markers and each marker's error, with the summaries a user reads (per marker,
the faulty ones, RMS over the trial). NumPy arrays, frame axis first.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float, Int

from .._body import Body, Pose
from .._joint_angles import angle_names, joint_angles
from .._opensim_coordinates import coordinate_names, opensim_coordinates
from ._mocap_solver import OUTLIER_SCALES


class MotionFit(eqx.Module):
    """What `fit_motion` returns: NumPy arrays, frame axis first."""

    FLAG_SHARE = 0.05  # `flagged` names a marker that is an outlier in more of the frames

    poses: Pose  # batched over frames (the spine as a Bendspine target)
    markers: Float[np.ndarray, "f n 3"]  # m, the model's markers
    errors: Float[np.ndarray, "f n"]  # m, model to measured; NaN where the marker was missing
    rms: Float[np.ndarray, " f"]  # m, root mean square of the present markers' errors
    max: Float[np.ndarray, " f"]  # m, the largest of them
    status: Int[np.ndarray, " f"]  # a FitStatus per frame
    steps: Int[np.ndarray, " f"]  # solver steps per frame
    times: Float[np.ndarray, " f"]  # s
    outliers: Bool[np.ndarray, "f n"]  # farther than OUTLIER_SCALES * scale from the model
    scale: float = eqx.field(static=True)  # m, the robust loss's scale
    names: tuple[str, ...] = eqx.field(static=True)  # the markers, the set's order
    kinds: tuple[str, ...] = eqx.field(static=True)  # "anatomical" | "tracking"
    # The markers left out before the fit, with why (`MarkerTrial.dead`): "no data" or
    # "does not move".
    dead: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())

    @property
    def outlier_distance(self) -> float:
        """m: the distance beyond which a marker is an outlier in its frame."""
        return OUTLIER_SCALES * self.scale

    def angles(self, body: Body) -> dict[str, np.ndarray]:
        """ISB joint angles of every frame (`joint_angles`), degrees, (f,) each; `body` is
        the body fitted (`StaticFit.body`)."""
        fn = jax.jit(jax.vmap(lambda pose: joint_angles(body, pose)))
        out = fn(self.poses)
        return {k: np.asarray(out[k]) for k in angle_names()}

    def coordinates(self, body: Body, frames=None) -> dict[str, np.ndarray]:
        """OpenSim's gait-model coordinates of every frame (`opensim_coordinates`; `frames`
        from `model_frames`), degrees and metres, (f,) each; `body` as for `angles`."""
        fn = jax.jit(jax.vmap(lambda pose: opensim_coordinates(body, pose, frames)))
        out = fn(self.poses)
        return {k: np.asarray(out[k]) for k in coordinate_names()}

    def pose(self, i: int) -> Pose:
        """Frame i's pose, as JAX arrays (ready for `forward`, `render`, ...)."""
        return jax.tree.map(lambda a: jnp.asarray(a[i]), self.poses)

    def per_marker(self) -> dict[str, tuple[float, float]]:
        """Per marker: (RMS over the frames that see it, largest error), m; NaN for a marker
        no frame sees."""
        rms, worst = rms_max(self.errors, axis=0)
        return {n: (float(r), float(m)) for n, r, m in zip(self.names, rms, worst)}

    def flagged(self) -> dict[str, str]:
        """The faulty markers, with why: each one left out ("no data", "does not move"),
        each one missing in more than `FLAG_SHARE` of the frames ("missing in 10 % of
        frames": gaps, or zeros read as gaps) and each one an outlier in more than
        `FLAG_SHARE` of the frames that see it ("outlier in 12 % of frames")."""
        out = dict(self.dead)
        seen = np.isfinite(self.errors).sum(axis=0)
        missing = 1.0 - seen / max(len(self.times), 1)
        share = self.outliers.sum(axis=0) / np.maximum(seen, 1)
        for name, gone, s in zip(self.names, missing, share):
            if name in out:
                continue
            why = []
            if gone > self.FLAG_SHARE:
                why.append(f"missing in {100 * gone:.0f} % of frames")
            if s > self.FLAG_SHARE:
                why.append(f"outlier in {100 * s:.0f} % of frames")
            if why:
                out[name] = ", ".join(why)
        return out

    def summary(self) -> dict[str, float]:
        """Mean and largest per-frame RMS and the largest error (m) over all markers; the
        RMS over all frames and markers, and over the inliers alone (`outliers` left out);
        the RMS over all frames of the anatomical and of the tracking markers apart."""
        inliers = np.where(self.outliers, np.nan, self.errors)
        out = {
            "mean_rms": float(np.nanmean(self.rms)),
            "max_rms": float(np.nanmax(self.rms)),
            "max_error": float(np.nanmax(self.max)),
            "rms": float(rms_max(self.errors.ravel(), axis=0)[0]),
            "inlier_rms": float(rms_max(inliers.ravel(), axis=0)[0]),
        }
        for kind in ("anatomical", "tracking"):
            cols = [k for k, c in enumerate(self.kinds) if c == kind]
            out[f"{kind}_rms"] = float(rms_max(self.errors[:, cols].ravel(), axis=0)[0])
        return out


def rms_max(errors: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Root mean square and largest of the finite errors along an axis; NaN where none."""
    seen = np.isfinite(errors)
    count = seen.sum(axis=axis)
    squares = np.where(seen, errors, 0.0) ** 2
    rms = np.where(count > 0, np.sqrt(squares.sum(axis) / np.maximum(count, 1)), np.nan)
    worst = np.where(count > 0, np.where(seen, errors, -np.inf).max(axis, initial=-np.inf), np.nan)
    return rms, worst
