"""The solvers' start points (diffbody.ik._starts): the Halton table."""

import numpy as np

from diffbody.ik._starts import MAX_STARTS, SPREAD, halton


def _radical_inverse(k: int, base: int) -> float:
    out, f = 0.0, 1.0 / base
    while k:
        k, digit = divmod(k, base)
        out += digit * f
        f /= base
    return out


def test_halton_starts_give_every_dimension_its_own_base():
    """Dimension d of the table is the radical inverse in the d-th prime, for every d of a
    whole-body problem (111 variables): d and d + 22 differ (a hand-written table cycled
    its bases after 22 primes), row 0 is the corner -SPREAD, and every value lies in
    [-SPREAD, SPREAD]."""
    primes = [p for p in range(2, 1000) if all(p % q for q in range(2, int(p**0.5) + 1))]
    table = halton(MAX_STARTS, 111)
    assert table.shape == (MAX_STARTS, 111) and np.all(np.abs(table) <= SPREAD)
    expected = [[_radical_inverse(k, primes[d]) for d in range(111)] for k in range(MAX_STARTS)]
    np.testing.assert_allclose(table, SPREAD * (2 * np.asarray(expected) - 1), atol=1e-12)
    for d in range(111 - 22):
        assert np.abs(table[1:, d] - table[1:, d + 22]).max() > 0.05, d
    np.testing.assert_array_equal(table[0], -SPREAD)
    assert halton(MAX_STARTS, 0).shape == (MAX_STARTS, 0)
