"""Tape or caliper readings of a body's length measurements beside a static trial
(`scale_and_register(measured=)`; docs/design.md, section 7): rows of the static fit."""

import math
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, unknown_name_error, without_names
from ..anthropometry._measurements import MEASUREMENTS
from ..anthropometry._scale_to import LENGTHS, linear_model_jit
from ..anthropometry._scaling import N_GROUPS

# A tape or caliper reading's standard deviation (m) when none is given: anthropometrists'
# technical error of measurement for stature, segment lengths and breadths is 2-5 mm (ISO
# 20685-1), so 5 mm.
TAPE_SD = 0.005


class Readings(eqx.Module):
    """Tape or caliper readings of the body's length measurements (`LENGTHS`, m): the
    modelled measurements A s (as `_Prior`'s) against the readings, each row over its
    standard deviation. A measurement not read weighs 0, so every set of readings shares one
    program."""

    A: Float[Array, "L two_n_group"]  # m per unit factor: axial columns, then radial
    value: Float[Array, " L"]  # m, 0 where not read
    inv_sd: Float[Array, " L"]  # 1 / m, 0 where not read

    def rows(self, log_axial: Array, log_radial: Array) -> Array:
        s = jnp.exp(jnp.concatenate([log_axial, log_radial]))
        return self.inv_sd * (self.A @ s - self.value)


def tape_readings(measured, template: Body, sd=TAPE_SD) -> Readings | None:
    """The static fit's readings (`Readings`; None when `measured` is empty or None).
    `measured`: measurement name (`LENGTHS`: stature, span, the segment lengths, breadths and
    depths of `diffbody.MEASUREMENTS`) -> metres, as ANSUR II measures them; `sd`: each
    reading's standard deviation (m), one for all or a dict by name."""
    if not measured:
        return None
    if not isinstance(measured, Mapping):
        raise TypeError(
            f"scale_and_register: measured must map measurement names to metres, "
            f'e.g. {{"stature": 1.78}}, got {measured!r}'
        )
    value, inv_sd = np.zeros(len(LENGTHS)), np.zeros(len(LENGTHS))
    for name, v in measured.items():
        if name not in LENGTHS:
            if name in MEASUREMENTS:
                raise ValueError(
                    f"scale_and_register: measured {name!r} is not a length; the static fit "
                    f"takes lengths in metres: {', '.join(LENGTHS)}"
                )
            raise unknown_name_error("measurement", name, LENGTHS)
        v = positive_number(f"measured {name!r}", v, "metres")
        if v > 3.0:
            raise ValueError(
                f"scale_and_register: measured {name!r} is {v:g}; give metres (a stature of "
                "1.78, not 1780 mm or 178 cm)"
            )
        given_sd = sd.get(name, TAPE_SD) if isinstance(sd, Mapping) else sd
        k = LENGTHS.index(name)
        value[k], inv_sd[k] = (
            v,
            1.0 / positive_number(f"measured_sd of {name!r}", given_sd, "metres"),
        )
    dtype = template.lengths.dtype
    arrays = (measurement_model(template), value, inv_sd)
    return Readings(*(jax.device_put(np.asarray(a, dtype)) for a in arrays))


def positive_number(what: str, v, unit: str) -> float:
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(
            f"scale_and_register: {what} must be a number of {unit}, got {v!r}"
        ) from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(
            f"scale_and_register: {what} must be a finite number of {unit} > 0, got {v!r}"
        )
    return v


def measurement_model(template: Body) -> np.ndarray:
    """(L, 2 n_group) A: the template's `LENGTHS` are A s for group factors s (axial, then
    radial) within the piece of s = 1 (`anthropometry._scale_to`)."""
    ones = jnp.ones(2 * N_GROUPS, template.lengths.dtype)
    return np.asarray(linear_model_jit(without_names(template), ones))
