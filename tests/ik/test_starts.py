"""The solvers' start points (diffbody.ik._starts): the Halton table."""

import numpy as np

from diffbody.ik._starts import MAX_STARTS, SPREAD, halton


def test_halton_starts_fill_the_range_without_repeating_dimensions():
    """Every dimension of a whole-body table (111 free variables) is its own sequence: no
    two move together (a hand-written table cycled its bases after 22 primes; unscrambled,
    neighbouring large primes nearly coincide), and every dimension spreads over
    [-SPREAD, SPREAD]: each eighth of it holds one of the 64 starts at least."""
    table = halton(MAX_STARTS, 111)
    assert table.shape == (MAX_STARTS, 111) and np.all(np.abs(table) <= SPREAD)
    columns = table[1:].T
    correlation = np.corrcoef(columns)
    np.fill_diagonal(correlation, 0.0)
    assert np.abs(correlation).max() < 0.7
    bins = np.floor((table + SPREAD) / (2 * SPREAD) * 8).astype(int)
    assert all(len(set(bins[:, d])) == 8 for d in range(111))
    assert halton(MAX_STARTS, 0).shape == (MAX_STARTS, 0)
    np.testing.assert_array_equal(halton(MAX_STARTS, 111), table)  # reproducible
