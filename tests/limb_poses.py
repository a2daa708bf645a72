"""Random postures of a few segments within their limits, the rest of the body at rest: the
targets of the reach tests."""

import jax
import numpy as np

import diffbody as db


def random_limb_angles(body, segments, rng, n):
    """(n, n_seg, 3) pose angles: `segments`' swing vectors and twists uniform within their
    limits (box, then pulled into the cone), the rest of the body in the standard position."""
    rest = body.rest_pose()
    idx = np.asarray([body.segment_index(s) for s in segments])
    lo, hi = np.asarray(body.swing_lo)[idx], np.asarray(body.swing_hi)[idx]
    w = lo + (hi - lo) * rng.uniform(size=(n, len(idx), 2))
    smax = np.asarray(body.swing_max)[idx]
    w *= np.minimum(1.0, smax / np.maximum(np.linalg.norm(w, axis=-1), 1e-300))[..., None]
    tlo, thi = np.asarray(body.twist_lo)[idx], np.asarray(body.twist_hi)[idx]
    W = np.repeat(np.asarray(db.swing_vector(body, rest.angles))[None], n, 0)
    W[:, idx] = w
    T = np.repeat(np.asarray(rest.angles[:, 2])[None], n, 0)
    T[:, idx] = tlo + (thi - tlo) * rng.uniform(size=(n, len(idx)))
    return jax.vmap(lambda w, t: db.angles_from_swing(body, w, t))(W, T)
