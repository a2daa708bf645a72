"""Argument checks of Bendspine and Movespine (docs/design.md, section 5).

A bad shape or dtype raises ValueError at once, also under jit. Values (ranges, finiteness,
the initiator inside the joint range) are checked on the host when concrete; when traced
(under jit, vmap or scan) by `equinox.error_if`, threaded onto the current angles so that it
raises at run time. Messages name the function and the argument.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._body import Spine


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _fmt(v: np.ndarray) -> str:
    """A scalar, or a vector as a tuple, as an error message shows it."""
    return repr(tuple(e.item() for e in v)) if v.ndim else repr(v.item())


def _show(x: np.ndarray, bad: np.ndarray) -> str:
    """The first offending value of x (bad: over x's leading axes), with its index."""
    if bad.ndim == 0:
        return _fmt(x)
    k = tuple(int(i) for i in np.argwhere(bad)[0])
    where = f"step {k[0]}" if len(k) == 1 else f"index {list(k)}"
    return f"{_fmt(np.asarray(x[k]))} at {where}"


class _Checker:
    """The checks of one call of `fn`: shapes and dtypes raise at once; values raise on the
    host when concrete, else they are collected for `guard` (`eqx.error_if` on `current`)."""

    def __init__(self, fn: str):
        self.fn = fn
        self.traced: list[tuple[Array, str]] = []

    def error(self, name: str, rule: str, got: str) -> ValueError:
        return ValueError(f"{self.fn}: {name} must {rule}, got {got}")

    def array(self, name, rule, x, kind, shapes):
        """x as an array: a jax array when traced, else a numpy one; `kind` "int" or "real"
        (int or float; bool never), of one of `shapes`."""
        items = x if isinstance(x, (tuple, list)) else (x,)
        if any(isinstance(e, (bool, np.bool_)) for e in items):
            raise self.error(name, rule, repr(x))
        if isinstance(x, (tuple, list)) and any(isinstance(e, jax.Array) for e in x):
            a = jnp.asarray(x)
        elif isinstance(x, jax.Array):
            a = x
        else:
            try:
                a = np.asarray(x)
            except (TypeError, ValueError, OverflowError):
                raise self.error(name, rule, repr(x)) from None
        ok = jnp.issubdtype(a.dtype, jnp.integer) or (
            kind == "real" and jnp.issubdtype(a.dtype, jnp.floating)
        )
        if not ok:
            small = not _is_traced(a) and np.size(a) <= 4
            raise self.error(name, rule, repr(x) if small else f"dtype {a.dtype}")
        if a.shape not in shapes:
            raise self.error(name, rule, f"shape {a.shape}")
        return a

    def values(self, name, rule, a, ok):
        """Require ok(xp, a) everywhere (xp: numpy on the host, jax.numpy when traced)."""
        if _is_traced(a):
            self.traced.append((~jnp.all(ok(jnp, a)), f"{self.fn}: {name} must {rule}"))
            return
        host = np.asarray(a)
        bad = np.asarray(~np.asarray(ok(np, host)))
        if np.any(bad):
            raise self.error(name, rule, _show(host, bad))

    def guard(self, x: Array) -> Array:
        """x carrying the traced checks: every output depends on it, so none is dead code."""
        for pred, msg in self.traced:
            x = eqx.error_if(x, pred, msg)
        return x


def checked_args(
    fn: str,
    spine: Spine,
    current,
    target,
    initiator,
    resistor,
    resistance,
    joint_range,
    zero_interpolation,
    spread,
    tol,
    steps,
):
    """Check Bendspine's arguments (`steps`: None for one call, else the number of steps of
    Movespine, whose per-step arguments may also have one value per step) and return them as
    the kernels' arrays: lower, upper, rest, current, target, initiator, resistor, resistance,
    joint_range, spread, tol, zero_interpolation."""
    n = spine.n_joints
    chk = _Checker(fn)
    per = "" if steps is None else f" (one value, or one per step: shape ({steps},))"
    per_pair = "" if steps is None else f" (one pair, or one per step: shape ({steps}, 2))"
    one = [()] if steps is None else [(), (steps,)]

    current = chk.array("current", f"be finite angles of shape ({n}, 3)", current, "real", [(n, 3)])
    if steps is None:
        target = chk.array("target", "have shape (3,)", target, "real", [(3,)])
    else:
        target = chk.array("targets", "have shape (n_step, 3)", target, "real", [(steps, 3)])
    dtypes = [
        a.dtype for a in (current, target, spine.lower) if jnp.issubdtype(a.dtype, jnp.floating)
    ]
    dtype = jax.dtypes.canonicalize_dtype(np.result_type(*dtypes))
    chk.values(
        "current", f"be finite angles of shape ({n}, 3)", current, lambda xp, a: xp.isfinite(a)
    )

    index_rule = f"be an integer joint index in [0, {n - 1}]{per}"
    initiator = chk.array("initiator", index_rule, initiator, "int", one)
    chk.values("initiator", index_rule, initiator, lambda xp, a: (a >= 0) & (a <= n - 1))
    resistance_rule = f"lie in [0, 1]{per}"
    resistance = chk.array("resistance", resistance_rule, resistance, "real", one)
    chk.values("resistance", resistance_rule, resistance, lambda xp, a: (a >= 0) & (a <= 1))
    if resistor is None:
        resistor, resistance = initiator, np.zeros(())
    else:
        resistor = chk.array("resistor", index_rule, resistor, "int", one)
        chk.values("resistor", index_rule, resistor, lambda xp, a: (a >= 0) & (a <= n - 1))

    range_rule = f"be two integers 0 <= from <= to <= {n - 1}{per_pair}"
    if joint_range is None:
        joint_range = np.asarray((0, n - 1))
    shapes = [(2,)] if steps is None else [(2,), (steps, 2)]
    joint_range = chk.array("joint_range", range_rule, joint_range, "int", shapes)
    chk.values(
        "joint_range",
        range_rule,
        joint_range,
        lambda xp, a: (a[..., 0] >= 0) & (a[..., 0] <= a[..., 1]) & (a[..., 1] <= n - 1),
    )
    if _is_traced(initiator) or _is_traced(joint_range):
        inside = (initiator >= joint_range[..., 0]) & (initiator <= joint_range[..., 1])
        chk.traced.append((~jnp.all(inside), f"{fn}: initiator must lie in joint_range"))
    else:
        i_h, r_h = np.asarray(initiator), np.asarray(joint_range)
        lead = np.broadcast_shapes(i_h.shape, r_h.shape[:-1])  # () or (steps,)
        i_h, r_h = np.broadcast_to(i_h, lead), np.broadcast_to(r_h, lead + (2,))
        bad = (i_h < r_h[..., 0]) | (i_h > r_h[..., 1])
        if np.any(bad):
            k = tuple(np.argwhere(bad)[0])
            at = f" at step {k[0]}" if k else ""
            raise chk.error("initiator", f"lie in joint_range {r_h[k].tolist()}", f"{i_h[k]}{at}")

    spread = chk.array("spread", "be finite and > 0", spread, "real", [()])
    chk.values("spread", "be finite and > 0", spread, lambda xp, a: xp.isfinite(a) & (a > 0))
    if tol is None:
        tol = 100 * n * float(jnp.finfo(dtype).eps)
    tol = chk.array("tol", "be finite and > 0 (or None)", tol, "real", [()])
    chk.values("tol", "be finite and > 0 (or None)", tol, lambda xp, a: xp.isfinite(a) & (a > 0))

    z = zero_interpolation
    if isinstance(z, (bool, np.bool_)):
        z = np.asarray(z)
    elif not (isinstance(z, (jax.Array, np.ndarray)) and z.dtype == bool and z.shape == ()):
        raise chk.error("zero_interpolation", "be a bool", repr(zero_interpolation))

    current = chk.guard(jnp.asarray(current, dtype))
    if steps is not None:
        lead = (steps,)
        initiator = jnp.broadcast_to(jnp.asarray(initiator), lead)
        resistor = jnp.broadcast_to(jnp.asarray(resistor), lead)
        resistance = jnp.broadcast_to(jnp.asarray(resistance), lead)
        joint_range = jnp.broadcast_to(jnp.asarray(joint_range), lead + (2,))
    # Fixed dtypes: Python, numpy and jax scalars all reach the kernel as the same arrays, so
    # that it compiles once.
    initiator, resistor, joint_range = (
        jnp.asarray(a, jnp.int32) for a in (initiator, resistor, joint_range)
    )
    return (
        jnp.asarray(spine.lower, dtype),
        jnp.asarray(spine.upper, dtype),
        jnp.asarray(spine.rest, dtype),
        current,
        jnp.asarray(target, dtype),
        initiator,
        resistor,
        jnp.asarray(resistance, dtype),
        joint_range,
        jnp.asarray(spread, dtype),
        jnp.asarray(tol, dtype),
        jnp.asarray(z, bool),
    )
