"""The population prior (docs/design.md, section 7): the joint distribution of the body
measurements of one sex in ANSUR II (Gordon et al. 2014; data/ansur2_subjects.csv), to
condition a body on the few measurements that are known.

It is a Gaussian of the measurements' logarithms. Body measurements are positive and their
spread grows with their size, so their logarithms are closer to Gaussian and a conditional
mean can never turn negative. The covariance is robust: the subjects are reweighted as under
a multivariate Student t (5 degrees of freedom), so that a few mis-keyed rows in the survey do
not tilt the regression that every other body follows. AddBiomechanics conditions a plain
Gaussian on height and weight; the held-out figures of both are in the README.
"""

from typing import NamedTuple

import numpy as np

from ..files._data_files import data_rows
from ._measurements import MEASUREMENT_NAMES, UNITS, check_names

SEXES = ("male", "female")
T_DOF = 5.0  # the Student t's degrees of freedom for the robust covariance


def ansur2_subjects(sex: str) -> tuple[np.ndarray, np.ndarray]:
    """ANSUR II subjects of one sex from data/ansur2_subjects.csv: their 0-based rows in the
    survey's file (n,), and their measurements (n, k) in `MEASUREMENT_NAMES` order, in
    metres (weightkg in kg)."""
    check_sex(sex)
    rows = [r for r in data_rows("ansur2_subjects.csv") if r["sex"] == sex]
    values = np.asarray([[float(r[n]) for n in MEASUREMENT_NAMES] for r in rows])
    to_si = np.asarray([1.0 if UNITS[n] == "kg" else 1e-3 for n in MEASUREMENT_NAMES])
    return np.asarray([int(r["row"]) for r in rows]), values * to_si


def check_sex(sex: str) -> str:
    if sex not in SEXES:
        raise ValueError(f"sex must be one of {SEXES}, got {sex!r}")
    return sex


class Conditional(NamedTuple):
    """The prior conditioned on which measurements are known (static index sets): for known
    log values x_k, the others' log values have mean `mean + gain @ (x_k - known_mean)` and
    covariance `cov`; `whiten` (u, u) maps their deviation to unit variance."""

    known: tuple[str, ...]
    unknown: tuple[str, ...]
    mean: np.ndarray  # (u,)
    known_mean: np.ndarray  # (k,)
    gain: np.ndarray  # (u, k)
    cov: np.ndarray  # (u, u)
    whiten: np.ndarray  # (u, u), inverse Cholesky factor of cov

    def unknown_mean(self, log_known: np.ndarray) -> np.ndarray:
        """(..., u) conditional means of the unknown log measurements."""
        return self.mean + (np.asarray(log_known) - self.known_mean) @ self.gain.T


class PopulationPrior:
    """Log-space Gaussian of the measurements of one sex (module docstring).

    Build it with `PopulationPrior.ansur2(sex)` (every subject of that sex, the default of
    `scale_to`) or `PopulationPrior.fit(values, sex=...)` from chosen rows.
    """

    def __init__(self, sex: str, names: tuple[str, ...], mean: np.ndarray, cov: np.ndarray, n: int):
        self.sex, self.names, self.n = check_sex(sex), tuple(names), int(n)
        self.mean, self.cov = np.asarray(mean, float), np.asarray(cov, float)

    def __repr__(self) -> str:
        return f"PopulationPrior({self.sex!r}, {len(self.names)} measurements, n={self.n})"

    @classmethod
    def fit(
        cls, values: np.ndarray, *, sex: str, names=MEASUREMENT_NAMES, robust: bool = True
    ) -> "PopulationPrior":
        """Fit to rows of measurements (n, k) in metres (weightkg in kg), columns `names`.
        `robust`: Student-t weights (module docstring); False: the sample covariance."""
        names = check_names(names)
        x = np.log(np.asarray(values, float))
        if x.ndim != 2 or x.shape[1] != len(names) or x.shape[0] <= len(names):
            raise ValueError(
                f"PopulationPrior.fit: values must be (n, {len(names)}) with n > {len(names)} "
                f"rows, got shape {np.shape(values)}"
            )
        if not np.all(np.isfinite(x)):
            raise ValueError("PopulationPrior.fit: every value must be finite and > 0")
        w = np.ones(len(x))
        for _ in range(50 if robust else 1):
            mean = w @ x / w.sum()
            d = x - mean
            cov = (w[:, None] * d).T @ d / len(x)
            if not robust:
                cov = d.T @ d / (len(x) - 1)
                break
            m2 = np.einsum("ij,ij->i", d @ np.linalg.inv(cov), d)
            w_new = (T_DOF + len(names)) / (T_DOF + m2)
            if np.max(np.abs(w_new - w)) < 1e-9:
                break
            w = w_new
        if robust:  # the t's scatter matrix -> its covariance
            cov = cov * T_DOF / (T_DOF - 2.0)
        return cls(sex, names, mean, cov, len(x))

    @classmethod
    def ansur2(cls, sex: str, rows: np.ndarray | None = None, robust: bool = True):
        """The prior of every ANSUR II subject of `sex`, or of the subjects whose 0-based row
        in the survey's file is in `rows`."""
        file_rows, values = ansur2_subjects(sex)
        if rows is not None:
            values = values[np.isin(file_rows, rows)]
        return cls.fit(values, sex=sex, robust=robust)

    def index(self, names) -> np.ndarray:
        names = check_names(names)
        missing = [n for n in names if n not in self.names]
        if missing:
            raise KeyError(f"the prior has no measurement {missing[0]!r}; it has {self.names}")
        return np.asarray([self.names.index(n) for n in names], dtype=int)

    def conditional(self, known) -> Conditional:
        """The prior given the measurements named in `known` (their values come later)."""
        k = self.index(known)
        u = np.setdiff1d(np.arange(len(self.names)), k)
        S = self.cov
        gain = (
            np.linalg.solve(S[np.ix_(k, k)], S[np.ix_(k, u)]).T if len(k) else np.zeros((len(u), 0))
        )
        cov = S[np.ix_(u, u)] - gain @ S[np.ix_(k, u)]
        whiten = np.linalg.inv(np.linalg.cholesky(cov))
        return Conditional(
            tuple(self.names[i] for i in k),
            tuple(self.names[i] for i in u),
            self.mean[u],
            self.mean[k],
            gain,
            cov,
            whiten,
        )

    def z_scores(self, names, values: np.ndarray) -> np.ndarray:
        """(n, k) how many standard deviations each of the named measurements (n, k) lies
        from its mean given the other k - 1 (in log space); with k = 1, from the mean."""
        names = check_names(names)
        x = np.log(np.atleast_2d(np.asarray(values, float)))
        z = np.zeros(x.shape)
        for i, name in enumerate(names):
            others = list(names[:i] + names[i + 1 :])
            c = self.conditional(others)
            j = c.unknown.index(name)
            mean = c.unknown_mean(np.delete(x, i, axis=1))[:, j]
            z[:, i] = (x[:, i] - mean) / np.sqrt(c.cov[j, j])
        return z

    def outliers(self, given: dict[str, float], sd: float = 6.0) -> list[str]:
        """Messages for the given measurements more than `sd` standard deviations from their
        mean given the other given ones (`z_scores`); [] when none is."""
        names = tuple(given)
        if not names:
            return []
        values = np.asarray([given[n] for n in names])
        z = self.z_scores(names, values[None])[0]
        out = []
        for i, name in enumerate(names):
            if abs(z[i]) <= sd:
                continue
            c = self.conditional(names[:i] + names[i + 1 :])
            j = c.unknown.index(name)
            mean = c.unknown_mean(np.log(np.delete(values, i)))[j]
            s = float(np.sqrt(c.cov[j, j]))
            lo, hi = np.exp(mean - sd * s), np.exp(mean + sd * s)
            unit = UNITS[name]
            others = f" given {', '.join(names[:i] + names[i + 1 :])}" if len(names) > 1 else ""
            out.append(
                f"{name} = {given[name]:g} {unit} is {abs(z[i]):.1f} standard deviations from "
                f"the {self.sex} population{others}; expected {lo:.3g} to {hi:.3g} {unit}"
            )
        return out

    def expected(self, given: dict[str, float]) -> dict[str, float]:
        """Every measurement of the prior: the given ones as given, the others at their
        conditional mean (the exponential of the mean of the logarithm: the median)."""
        c = self.conditional(list(given))
        mean = c.unknown_mean(np.log([given[n] for n in c.known]))
        values = dict(zip(c.unknown, np.exp(mean)))
        values.update(given)
        return {n: float(values[n]) for n in self.names}
