"""A structured linear least-squares solver (lineax) for problems over the frames of a
sequence: per-frame unknowns, a few unknowns shared by all frames (the *border*: lengths,
the focal length), residual rows that see one frame, and rows that see a window of three
consecutive frames of one entity (a joint's or a part's acceleration).

Its normal matrix is block-pentadiagonal (blocks of the frame's unknowns) with a dense
border. `BandedSchurCholesky` forms it from the operator by a few colored products (the
Jacobian's columns of one frame never meet in a window row of another frame three apart),
factors the frame blocks by a block-banded Cholesky (a `lax.scan` over frames), and
eliminates the border by its Schur complement: O(T n^3) instead of O((T n)^3) for a dense
solve of T frames of n unknowns.

It serves optimistix's Gauss-Newton and Levenberg-Marquardt: their operator is the
Jacobian J (`FrameResiduals` out) or the damped stack [J; sqrt(lambda) I] (a tuple of
`FrameResiduals` and `FrameUnknowns`); the damping's diagonal is read off the same products.
"""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import lineax as lx
from jaxtyping import Array, Float

WINDOW = 3  # frames seen by a window row


class FrameUnknowns(eqx.Module):
    """Unknowns: `border` shared by every frame, `frames` per frame and entity."""

    border: Float[Array, "*b m"]
    frames: Float[Array, "*b n_frames n_ent q"]


class FrameResiduals(eqx.Module):
    """Residuals: row t of `frame` depends on frames[t] (all entities) and the border; rows
    (t, e) of `window` on frames[t : t + 3, e] (entity e only) and the border."""

    frame: Float[Array, "*b n_frames a"]
    window: Float[Array, "*b n_windows n_ent r"]


def _probes(T: int, E: int, q: int, m: int, dtype) -> FrameUnknowns:
    """Unit directions whose products with J give every nonzero of J once: one per frame
    unknown (k) for all frames together (frame rows see one frame), one per (color, j) for
    window rows (frames three apart and different entities never share a row), one per
    border unknown."""
    n = E * q
    eye_n = jnp.eye(n, dtype=dtype).reshape(n, 1, E, q)
    per_frame = jnp.broadcast_to(eye_n, (n, T, E, q))
    color = (jnp.arange(T)[None, :] % WINDOW) == jnp.arange(WINDOW)[:, None]  # (3, T)
    j_eye = jnp.eye(q, dtype=dtype)
    windowed = color[:, None, :, None, None] * j_eye[None, :, None, None, :]  # (3, q, T, 1, q)
    windowed = jnp.broadcast_to(windowed, (WINDOW, q, T, E, q)).reshape(WINDOW * q, T, E, q)
    frames = jnp.concatenate([per_frame, windowed, jnp.zeros((m, T, E, q), dtype)])
    border = jnp.concatenate([jnp.zeros((n + WINDOW * q, m), dtype), jnp.eye(m, dtype=dtype)])
    return FrameUnknowns(border=border, frames=frames)


class _State(eqx.Module):
    Jf: Array  # (T, a, n)
    Jfb: Array  # (T, a, m)
    Jw: Array  # (T', E, r, 3, q)
    Jwb: Array  # (T', E, r, m)
    damp_f: Array  # (T, n) sqrt(lambda) of the frame unknowns (0 without damping)
    damp_b: Array  # (m,)
    Ltt: Array  # (T, n, n) diagonal Cholesky blocks
    L1: Array  # (T, n, n) block (t + 1, t)
    L2: Array  # (T, n, n) block (t + 2, t)
    YB: Array  # (T, n, m) L^-1 B
    Ls: Array  # (m, m) Cholesky factor of the border's Schur complement
    damped: bool = eqx.field(static=True)


def _blockdiag(blocks: Array) -> Array:
    """(..., E, q, q) entity blocks -> (..., E q, E q) block-diagonal matrix."""
    *lead, E, q, _ = blocks.shape
    eye = jnp.eye(E, dtype=blocks.dtype)
    full = blocks[..., :, :, None, :] * eye[:, None, :, None]  # (..., E, q, E, q)
    return full.reshape(*lead, E * q, E * q)


def _forward(Ltt: Array, L1: Array, L2: Array, R: Array) -> Array:
    """L^-1 R for the block-banded lower factor (blocks Ltt, L1 = L[t+1, t], L2 = L[t+2, t]);
    R (T, n, k)."""
    T, n, k = R.shape
    zero = jnp.zeros((n, k), R.dtype)
    L1p = jnp.concatenate([jnp.zeros_like(L1[:1]), L1[:-1]])  # L[t, t-1]
    L2p = jnp.concatenate([jnp.zeros_like(L2[:2]), L2[:-2]])  # L[t, t-2]

    def step(carry, x):
        y1, y2 = carry  # y[t-1], y[t-2]
        L, a, b, r = x
        y = jsl.solve_triangular(L, r - a @ y1 - b @ y2, lower=True)
        return (y, y1), y

    _, Y = jax.lax.scan(step, (zero, zero), (Ltt, L1p, L2p, R))
    return Y


def _backward(Ltt: Array, L1: Array, L2: Array, Z: Array) -> Array:
    """L^-T Z (the transpose of `_forward`)."""
    T, n, k = Z.shape
    zero = jnp.zeros((n, k), Z.dtype)

    def step(carry, x):
        x1, x2 = carry  # x[t+1], x[t+2]
        L, a, b, z = x
        xt = jsl.solve_triangular(L, z - a.T @ x1 - b.T @ x2, lower=True, trans="T")
        return (xt, x1), xt

    _, X = jax.lax.scan(step, (zero, zero), (Ltt, L1, L2, Z), reverse=True)
    return X


class BandedSchurCholesky(lx.AbstractLinearSolver[_State]):
    """Least squares min |A x - b| for operators FrameUnknowns -> FrameResiduals (or the
    damped [J; sqrt(lambda) I]) by the normal equations, a block-banded Cholesky over the
    frames and the border's Schur complement (module docstring). The normal matrix must be
    positive definite (damping makes it so); a failed factorisation reports
    `RESULTS.singular`."""

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]) -> _State:
        del options
        x_struct = operator.in_structure()
        out = operator.out_structure()
        damped = isinstance(out, tuple)
        res_struct = out[0] if damped else out
        T, E, q = x_struct.frames.shape
        (m,) = x_struct.border.shape
        Tw, _, r = res_struct.window.shape
        n = E * q
        dtype = x_struct.frames.dtype
        probes = _probes(T, E, q, m, dtype)
        outs = jax.vmap(operator.mv)(probes)
        res = outs[0] if damped else outs
        # frame rows: J_f[t][:, k] from probe k
        Jf = jnp.moveaxis(res.frame[:n], 0, -1)  # (T, a, n)
        Jfb = jnp.moveaxis(res.frame[n + WINDOW * q :], 0, -1)  # (T, a, m)
        win = res.window[n : n + WINDOW * q].reshape(WINDOW, q, Tw, E, r)
        t = jnp.arange(Tw)
        # window t, position s in it: frame t + s, whose color is (t + s) % 3
        Jw = jnp.stack([win[(t + s) % WINDOW, :, t] for s in range(WINDOW)])  # (3, T', q, E, r)
        Jw = jnp.transpose(Jw, (1, 3, 4, 0, 2))  # (T', E, r, 3, q)
        Jwb = jnp.moveaxis(res.window[n + WINDOW * q :], 0, -1)  # (T', E, r, m)
        if damped:
            dmp = outs[1]
            idx = jnp.arange(n)
            damp_f = dmp.frames[:n].reshape(n, T, n)[idx, :, idx].T  # (T, n)
            damp_b = jnp.diagonal(dmp.border[n + WINDOW * q :])
        else:
            damp_f = jnp.zeros((T, n), dtype)
            damp_b = jnp.zeros(m, dtype)

        # --- the normal matrix H = J^T J + D^2, in blocks
        A0 = jnp.einsum("tai,taj->tij", Jf, Jf) + jax.vmap(jnp.diag)(damp_f**2)
        sq = jnp.einsum("tersi,tersj->tseij", Jw, Jw)  # (T', 3, E, q, q)
        for s in range(WINDOW):
            A0 = A0.at[s : s + Tw].add(_blockdiag(sq[:, s]))
        A1 = jnp.zeros((T, n, n), dtype)  # block (t, t+1)
        A1 = A1.at[:Tw].add(_blockdiag(jnp.einsum("teri,terj->teij", Jw[..., 0, :], Jw[..., 1, :])))
        A1 = A1.at[1 : Tw + 1].add(
            _blockdiag(jnp.einsum("teri,terj->teij", Jw[..., 1, :], Jw[..., 2, :]))
        )
        A2 = jnp.zeros((T, n, n), dtype)  # block (t, t+2)
        A2 = A2.at[:Tw].add(_blockdiag(jnp.einsum("teri,terj->teij", Jw[..., 0, :], Jw[..., 2, :])))
        B = jnp.einsum("tai,tam->tim", Jf, Jfb)
        for s in range(WINDOW):
            Bs = jnp.einsum("teri,term->teim", Jw[..., s, :], Jwb).reshape(Tw, n, m)
            B = B.at[s : s + Tw].add(Bs)
        C = (
            jnp.einsum("tai,taj->ij", Jfb, Jfb)
            + jnp.einsum("teri,terj->ij", Jwb, Jwb)
            + jnp.diag(damp_b**2)
        )

        # --- block-banded Cholesky of the frame part
        zero = jnp.zeros((n, n), dtype)

        def step(carry, x):
            m1, m2, n1 = carry  # L[t, t-1], L[t, t-2], L[t+1, t-1]
            a0, a1, a2 = x
            L = jnp.linalg.cholesky(a0 - m1 @ m1.T - m2 @ m2.T)
            l1 = jsl.solve_triangular(L, (a1 - m1 @ n1.T), lower=True).T  # L[t+1, t]
            l2 = jsl.solve_triangular(L, a2, lower=True).T  # L[t+2, t]
            return (l1, n1, l2), (L, l1, l2)

        _, (Ltt, L1, L2) = jax.lax.scan(step, (zero, zero, zero), (A0, A1, A2))
        YB = _forward(Ltt, L1, L2, B)
        Ls = jnp.linalg.cholesky(C - jnp.einsum("tim,tik->mk", YB, YB))
        return _State(Jf, Jfb, Jw, Jwb, damp_f, damp_b, Ltt, L1, L2, YB, Ls, damped)

    def compute(self, state: _State, vector, options: dict[str, Any]):
        del options
        res = vector[0] if state.damped else vector
        Jw, Tw = state.Jw, state.Jw.shape[0]
        T, _, n = state.Jf.shape
        E, q = Jw.shape[1], Jw.shape[-1]
        # g = A^T b
        gf = jnp.einsum("tai,ta->ti", state.Jf, res.frame)
        for s in range(WINDOW):
            gs = jnp.einsum("teri,ter->tei", Jw[..., s, :], res.window).reshape(Tw, n)
            gf = gf.at[s : s + Tw].add(gs)
        gb = jnp.einsum("tam,ta->m", state.Jfb, res.frame) + jnp.einsum(
            "term,ter->m", state.Jwb, res.window
        )
        if state.damped:
            gf = gf + state.damp_f * vector[1].frames.reshape(T, n)
            gb = gb + state.damp_b * vector[1].border
        yg = _forward(state.Ltt, state.L1, state.L2, gf[..., None])[..., 0]
        rhs = gb - jnp.einsum("tim,ti->m", state.YB, yg)
        db = jsl.cho_solve((state.Ls, True), rhs)
        z = yg - jnp.einsum("tim,m->ti", state.YB, db)
        df = _backward(state.Ltt, state.L1, state.L2, z[..., None])[..., 0]
        x = FrameUnknowns(border=db, frames=df.reshape(T, E, q))
        ok = jnp.all(jnp.isfinite(df)) & jnp.all(jnp.isfinite(db))
        x = jax.tree.map(lambda v: jnp.where(ok, v, 0.0), x)
        return x, lx.RESULTS.where(ok, lx.RESULTS.successful, lx.RESULTS.singular), {}

    def transpose(self, state: _State, options: dict[str, Any]):
        # The damped normal equations are symmetric: the transpose solves the same system.
        return state, options

    def conj(self, state: _State, options: dict[str, Any]):
        return state, options

    def assume_full_rank(self) -> bool:
        return True
