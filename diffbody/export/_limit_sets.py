"""The rotations a segment's limits allow, sampled on the host (float64 NumPy), for the
exports: the largest angle of a ball joint (`ball_ranges`) and three hinges whose
singularity lies outside the limits, with their bounds (`euler_hinges`).

A segment's rotation from its rest frame R_rest (the standard position's cross of axes in
its socket, `Body.R_socket_rest`) is

    Q(w, tau) = R_rest^T R_socket_twisted = M(w) Rz(tau),

M(w) = exp([w_x, w_y, 0]) for the swing default, turned further about its own Z by the limb
table's twist for the limbs (`socket_frames_from_swing`). The limits (`_limits.py`) allow
the set {lo <= w <= hi, |w| <= swing_max} x [twist_lo, twist_hi], which holds w = 0,
tau = 0 (the rest pose). Neither format can state that set; `within_limits` checks it.

How the set is sampled, and why the bounds hold. w runs over a grid of the box with spacing
at most `SWING_STEP` (`HINGE_STEP` for the hinges), points outside the cone pulled radially
onto it (they stay in the box: it is convex and holds w = 0), so the samples reach every
edge of the set. A bound is the extreme value over the samples, widened by the largest
change of that value between neighbouring samples: a function that changes by at most that
much from one sample to the next cannot exceed the samples by more between them. The
ball's angle is maximised over tau exactly (`_largest_angle_over_twist`); the hinges'
values are sampled in tau too.
"""

import warnings
from dataclasses import dataclass

import jax
import numpy as np
from scipy.spatial.transform import Rotation

from .._body import Body
from .._body_cache import BodyCache
from .._kinematics import KINDS, socket_frame_of_kind

# rad, added to every bound: more than `within_limits`' tolerance (256 eps) and the rounding
# of frames computed through `forward`, so a pose on a limit is within the bound.
ROUNDING = 1e-9
SWING_STEP = np.deg2rad(1.0)  # rad, grid spacing of the swing vector for the ball ranges
HINGE_STEP = np.deg2rad(2.0)  # rad, grid spacing in (w_x, w_y, tau) for the hinge bounds
ALIGNED_MARGIN = np.deg2rad(10.0)  # rad, least distance to the singularity of aligned hinges
N_FRAMES = 4096  # hinge frames tried when no aligned one keeps that distance


def _swing_grid(body: Body, i: int, step: float) -> np.ndarray:
    """(n_0, n_1, 2) swing vectors (rad) over segment i's limit set: a grid of its box with
    spacing <= step, points outside its cone pulled radially onto it."""
    lo = np.asarray(body.swing_lo[i], np.float64)
    hi = np.asarray(body.swing_hi[i], np.float64)
    axes = [np.linspace(a, b, max(2, int(np.ceil((b - a) / step)) + 1)) for a, b in zip(lo, hi)]
    axes = [np.unique(np.append(x, 0.0)) if x[0] < 0 < x[-1] else x for x in axes]  # the rest
    w = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    norm = np.linalg.norm(w, axis=-1, keepdims=True)
    cone = float(body.swing_max[i])
    return np.where(norm > cone, w * cone / np.where(norm > 0, norm, 1.0), w)


CHUNK = 16384  # samples per call of `_socket_frames`: one compiled program serves all

# forward's own socket frame (`socket_frame_of_kind`) over a chunk of directions.
_socket_frames = jax.jit(jax.vmap(socket_frame_of_kind, in_axes=(0, 0, None, None)))


def _rest_relative_swings(body: Body, i: int, w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) M(w) = R_rest^T R_socket_base(w) of segment i for swing vectors (..., 2):
    the direction exp(w) turns the rest frame's Z to, as (theta, phi) in the socket, through
    the base frame `forward` builds there (its limb table or the swing default)."""
    flat = w.reshape(-1, 2)
    a = np.linalg.norm(flat, axis=-1)
    sinc = np.sinc(a / np.pi)  # sin(a) / a
    d_rest = np.stack([flat[:, 1] * sinc, -flat[:, 0] * sinc, np.cos(a)], axis=-1)
    R_rest = np.asarray(body.R_socket_rest[i], np.float64)
    d = d_rest @ R_rest.T
    theta = np.arctan2(d[:, 1], d[:, 0])
    phi = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    kind = KINDS.index(body.standard_kind[i])
    pad = -len(flat) % CHUNK
    theta, phi = np.pad(theta, (0, pad)), np.pad(phi, (0, pad))
    R = np.concatenate(
        [
            np.asarray(_socket_frames(t, p, R_rest, kind), np.float64)
            for t, p in zip(theta.reshape(-1, CHUNK), phi.reshape(-1, CHUNK))
        ]
    )[: len(flat)]
    return (R_rest.T @ R).reshape(w.shape[:-1] + (3, 3))


def _twist_range(body: Body, i: int) -> tuple[float, float]:
    return float(body.twist_lo[i]), float(body.twist_hi[i])


def _largest_angle_over_twist(M: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(...,) the largest rotation angle (rad, in [0, pi]) of M Rz(tau) over tau in [lo, hi].

    trace(M Rz(tau)) = A cos(tau) + B sin(tau) + M_22 = C cos(tau - phi) + M_22 with
    A = M_00 + M_11, B = M_01 - M_10: the angle is largest where cos(tau - phi) is least,
    -1 if tau = phi + pi (mod 2 pi) lies in the range, else at an end of it."""
    A, B = M[..., 0, 0] + M[..., 1, 1], M[..., 0, 1] - M[..., 1, 0]
    C, phi = np.hypot(A, B), np.arctan2(B, A)
    first = phi + np.pi + 2 * np.pi * np.ceil((lo - phi - np.pi) / (2 * np.pi))
    least = np.where(first <= hi, -1.0, np.minimum(np.cos(lo - phi), np.cos(hi - phi)))
    trace = C * least + M[..., 2, 2]
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def _neighbour_change(values: np.ndarray) -> float:
    """The largest change of a gridded value between neighbouring samples (any axis)."""
    steps = [np.abs(np.diff(values, axis=k)) for k in range(values.ndim) if values.shape[k] > 1]
    return max((float(s.max()) for s in steps), default=0.0)


def ball_ranges(body: Body) -> np.ndarray:
    """(n_seg,) the largest rotation (rad, in [0, pi]) from the rest frame that segment i's
    limits allow (a ball joint's range about the rest frame); inf for "free" segments.

    The largest of the sampled angles (module docstring), widened by their largest change
    between neighbouring samples and `ROUNDING`, capped at pi."""
    out = np.full(body.n_segments, np.inf)
    for i, kind in enumerate(body.limit_kind):
        if kind == "free":
            continue
        angle = _largest_angle_over_twist(
            _rest_relative_swings(body, i, _swing_grid(body, i, SWING_STEP)),
            *_twist_range(body, i),
        )
        out[i] = min(np.pi, float(angle.max()) + _neighbour_change(angle) + ROUNDING)
    return out


@dataclass(frozen=True)
class EulerHinges:
    """Three hinges for one segment: Q = R_a(q_0) R_b(q_1) R_c(q_2), (a, b, c) = `axes`.

    axes: (3, 3) unit hinge axes (rows) in the rest frame, each in the frame the hinges
        before it leave (intrinsic rotations): the columns of a rotation F, so that
        F^T Q F = Rx(q_0) Ry(q_1) Rz(q_2).
    lower, upper: (3,) rad, bounds of the hinge values over the limit set.
    singular_margin: rad, pi/2 - max |q_1| over the limit set: how far the limits stay from
        the middle hinge's singularity (q_1 = +-pi/2, where a and c align).
    """

    axes: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    singular_margin: float


def hinge_values(axes: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """(..., 3) values (rad, q_0 and q_2 in [-pi, pi], q_1 in [-pi/2, pi/2]) of the hinges
    `axes` (`EulerHinges.axes`) for rotations from the rest frame Q (..., 3, 3).

    At the singularity (outside the limits) scipy keeps q_2 = 0; the values still give Q."""
    F = axes.T
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        angles = Rotation.from_matrix((F.T @ Q @ F).reshape(-1, 3, 3)).as_euler("XYZ")
    return angles.reshape(Q.shape[:-2] + (3,))


def _bounds(values: np.ndarray) -> tuple[float, float]:
    """Bounds of one hinge's gridded values: the sampled extremes widened by their largest
    neighbour change and `ROUNDING`; [-pi, pi] when the values wrap around (a jump of over
    pi)."""
    change = _neighbour_change(values) + ROUNDING
    if change > np.pi:
        return -np.pi, np.pi
    return max(-np.pi, float(values.min()) - change), min(np.pi, float(values.max()) + change)


def _aligned_frames() -> np.ndarray:
    """(6, 3, 3) the hinge frames F about the rest frame's own axes, every order of x, y, z
    (one axis negated where the order is odd, to keep F a rotation), those ending in z
    first: the last hinge is then the segment's twist about its own axis."""
    frames = []
    for order in ("xyz", "yxz", "zxy", "zyx", "xzy", "yzx"):
        F = np.eye(3)[:, ["xyz".index(a) for a in order]]
        frames.append(F * np.array([1.0, np.linalg.det(F), 1.0]))
    return np.stack(frames)


def _sin_middle(frames: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """(n_frames,) max |sin q_1| = max |f_x . Q f_z| over rotations Q (k, 3, 3)."""
    s = np.einsum("fi,kij,fj->fk", frames[:, :, 0], Q, frames[:, :, 2], optimize=True)
    return np.abs(s).max(axis=1)


def _hinge_frame(Q: np.ndarray) -> np.ndarray:
    """The hinge frame F (3, 3) whose singularity lies farthest from the rotations Q
    (..., 3, 3): the first of `_aligned_frames` that is as far as any of them, unless
    they all come within `ALIGNED_MARGIN` of it (a shoulder reaches every axis); then the
    farthest of `N_FRAMES` quasi-random frames, judged on every fourth sample and the best
    few on all of them."""
    flat = Q.reshape(-1, 3, 3)
    aligned = _aligned_frames()
    sin_b = _sin_middle(aligned, flat)
    best = int(np.argmax(sin_b <= sin_b.min() + 1e-12))
    if np.arcsin(min(1.0, sin_b[best])) <= np.pi / 2 - ALIGNED_MARGIN:
        return aligned[best]
    frames = Rotation.from_quat(_uniform_quaternions(N_FRAMES)).as_matrix()
    coarse = _sin_middle(frames, Q[::4, ::4, ::4].reshape(-1, 3, 3))
    few = frames[np.argsort(coarse)[:8]]
    candidates = np.concatenate([aligned[best : best + 1], few])
    return candidates[int(np.argmin(_sin_middle(candidates, flat)))]


def _uniform_quaternions(n: int) -> np.ndarray:
    """(n, 4) quaternions uniform over the rotations (Shoemake's map of uniform numbers,
    fixed seed: the same frames every run)."""
    u = np.random.default_rng(0).uniform(size=(n, 3))
    a, b = np.sqrt(1 - u[:, 0]), np.sqrt(u[:, 0])
    t1, t2 = 2 * np.pi * u[:, 1], 2 * np.pi * u[:, 2]
    return np.stack([a * np.sin(t1), a * np.cos(t1), b * np.sin(t2), b * np.cos(t2)], axis=-1)


# What `segment_euler_hinges` reads: the limits and the standard frames.
_HINGES = BodyCache(
    ("swing_lo", "swing_hi", "swing_max", "twist_lo", "twist_hi", "R_socket_rest"), size=16
)


def euler_hinges(body: Body) -> list[EulerHinges]:
    """`segment_euler_hinges`, computed once per set of limits (a few seconds) and kept:
    `urdf_joint_values` needs it for every pose."""
    return _HINGES.get(body, None, lambda: segment_euler_hinges(body))


def segment_euler_hinges(body: Body) -> list[EulerHinges]:
    """Per segment, three hinges whose singularity lies outside its limit set
    (`_hinge_frame`), and the bounding box of the set in their values (module docstring:
    sampled, widened). A "free" segment gets x, y, z and [-pi, pi] (margin 0: no limit
    keeps it from the singularity)."""
    out = []
    for i, kind in enumerate(body.limit_kind):
        if kind == "free":
            full = np.full(3, np.pi)
            out.append(EulerHinges(np.eye(3), -full, full, 0.0))
            continue
        M = _rest_relative_swings(body, i, _swing_grid(body, i, HINGE_STEP))
        lo, hi = _twist_range(body, i)
        tau = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / HINGE_STEP)) + 1))
        Q = M[:, :, None] @ Rotation.from_euler("z", tau[:, None]).as_matrix()
        F = _hinge_frame(Q)
        values = hinge_values(F.T, Q)
        b = np.abs(values[..., 1])
        margin = np.pi / 2 - (float(b.max()) + _neighbour_change(b))
        bounds = np.array([_bounds(values[..., k]) for k in range(3)])
        out.append(EulerHinges(F.T, bounds[:, 0], bounds[:, 1], margin))
    return out
