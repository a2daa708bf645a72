"""The start search of a sphere-cloud fit without correspondences
(diffbody.clouds._cloud_start) and how a fit that cannot land says so."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.anthropometry._scaling import per_segment
from diffbody.clouds._cloud_fit import LANDED_INLIERS
from diffbody.clouds._cloud_residuals import FIT_NAMES, fit_layout
from diffbody.clouds._cloud_start import search_spheres, search_tables

SPREAD = 0.3  # posture spread, as a user's clouds (benchmarks/_sphere_cloud.py)
LANDED = 0.002  # m: a fit lands when its mean segment-length error is below this


def person_cloud(body, seed: int, turn: float | None):
    """A scaled person (group factors exp(N(0, 0.05^2))) at posture spread 0.3, measured
    with 5 mm noise and 10 % outliers: (centers, radii, segment lengths). turn: the whole
    body turned about the vertical through the cloud's median by this angle (rad) from
    facing +X; None: any angle, as `sample_pose` draws it."""
    key = jax.random.PRNGKey(seed)
    g = len(db.SCALE_GROUPS)
    k_ax, k_ra, k_pose, k_cloud = jax.random.split(key, 4)
    axial = jnp.exp(0.05 * jax.random.normal(k_ax, (g,)))
    radial = jnp.exp(0.05 * jax.random.normal(k_ra, (g,)))
    person = db.scale_body(body, per_segment(body, axial), per_segment(body, radial))
    pose = db.sample_pose(body, k_pose, spread=SPREAD, turn=np.pi if turn is None else 0.0)
    centers, radii, _ = db.synthetic_cloud(person, pose, k_cloud, 0.005, 0.1)
    centers = np.asarray(centers)
    if turn is not None:
        c, s = np.cos(turn), np.sin(turn)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        middle = np.median(centers, axis=0)
        centers = (centers - middle) @ Rz.T + middle
    return centers, np.asarray(radii), np.asarray(person.lengths)


def three_clouds(male50):
    """A person turned 180 degrees, one turned any way, and a cloud that is no body (spheres
    drawn in a box): centers, radii, true lengths, stacked."""
    clouds = [person_cloud(male50, 3, np.pi), person_cloud(male50, 4, None)]
    rng = np.random.default_rng(0)
    m = len(clouds[0][1])
    box = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], (m, 3))
    clouds.append((box, rng.uniform(0.01, 0.08, m), clouds[0][2]))
    return (np.stack(a) for a in zip(*clouds))


@pytest.fixture(scope="module")
def fits(male50):
    """One batch, one compiled program, of `three_clouds`: (fit, true lengths)."""
    centers, radii, lengths = three_clouds(male50)
    fit = db.fit_spheres_batch(male50, centers, radii, chunk_size=3, progress=False)
    return fit, lengths


def length_error(fit, lengths, i) -> float:
    keep = lengths[i] > 0
    return float(np.mean(np.abs(np.asarray(fit.body.lengths[i]) - lengths[i])[keep]))


def test_a_person_turned_any_way_lands_without_correspondences(fits):
    """Spread 0.3, 5 mm noise, 10 % outliers, no correspondences, no `init`: the search
    finds the heading and the limbs, the fit lands (mean length error < 2 mm; 1.53 mm
    today) and says so."""
    fit, lengths = fits
    error = length_error(fit, lengths, 1)
    assert error < LANDED, f"mean segment-length error {1e3 * error:.2f} mm"
    # Landed, not failed; CONVERGED is rarer (float32 or float64, the last EM rounds seldom
    # stand still within 100x the tolerance in their 6 steps: the benchmark's "converged").
    assert fit.landed[1] and fit.status[1] != db.FitStatus.FAILED
    assert np.mean(fit.inliers[1]) >= LANDED_INLIERS


@pytest.mark.parametrize("i", [0, 1])
def test_a_fit_of_a_person_says_whether_it_landed(fits, i):
    """Each person's fit says landed exactly when it did (mean length error < 2 mm), and is
    CONVERGED only then. The cloud turned 180 degrees (i = 0) does not land today (mean
    error 16 mm, worst segment 92 mm, 72 % inliers), and its fit says so. Landing such
    clouds is the benchmark's unmet goal (docs/benchmarks.md, sphere-cloud fits: 95 % of
    the clouds turned any way)."""
    fit, lengths = fits
    error = length_error(fit, lengths, i)
    assert bool(fit.landed[i]) == (error < LANDED), f"mean error {1e3 * error:.2f} mm"
    assert fit.status[i] != db.FitStatus.CONVERGED or fit.landed[i]


def test_a_cloud_that_is_no_body_is_reported_as_not_landed(fits):
    """Spheres drawn in a box: no start lands, and the result says so (few inliers, not
    landed, never CONVERGED), with finite numbers."""
    fit, _ = fits
    assert not fit.landed[2]
    assert fit.status[2] != db.FitStatus.CONVERGED
    assert np.mean(fit.inliers[2]) < LANDED_INLIERS
    assert np.all(np.isfinite(fit.residuals[2])) and np.all(np.isfinite(fit.axial[2]))


def test_the_search_tables(male50):
    """Each group's grid starts at the current values, holds every point of its 3^k grid
    once, and moves only its own free components; the compared spheres cover every segment
    that carries a sphere."""
    lay = fit_layout(male50, FIT_NAMES)
    index, grid, keep = (np.asarray(t) for t in search_tables(male50, lay))
    assert np.all(grid[:, 0] == 0)
    for cols, offsets in zip(index, grid):
        k = len(set(cols.tolist()))
        points = {tuple(np.sign(o[:k])) for o in offsets}
        assert len(points) == 3**k
        assert np.all(offsets[:, k:] == 0)
    seg = np.asarray(male50.sphere_segment)
    assert set(seg[keep]) == set(seg)
    assert np.array_equal(keep, search_spheres(male50))


def test_a_batch_kept_in_a_folder_resumes_after_an_interrupt(fits, male50, tmp_path, monkeypatch):
    """fit_spheres_batch(out=): the fixture's clouds twice, in two chunks of the same
    compiled size; an interrupt in the second keeps the first (`Interrupted` says so);
    resume=True reads it and fits the second: every cloud as the fixture's one call fits
    it. Other clouds are refused by name."""
    import diffbody.clouds._cloud_fit as sphere_fit
    from diffbody.runs._streaming import Interrupted

    fit, _ = fits
    centers, radii, _ = (np.concatenate([a] * 2) for a in three_clouds(male50))
    run, calls = sphere_fit._fit_many_jit, []

    def run_then_stop(*args):
        if not isinstance(jax.tree.leaves(args[3])[0], jax.core.Tracer):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt
        return run(*args)

    monkeypatch.setattr(sphere_fit, "_fit_many_jit", run_then_stop)
    kept = tmp_path / "clouds"
    with pytest.raises(Interrupted, match=f"interrupted after 3 of 6 rows; {kept} holds them"):
        db.fit_spheres_batch(male50, centers, radii, chunk_size=3, progress=False, out=kept)
    with pytest.raises(ValueError, match="clouds changed from "):
        db.fit_spheres_batch(male50, centers + 0.01, radii, chunk_size=3, out=kept, resume=True)
    resumed = db.fit_spheres_batch(
        male50, centers, radii, chunk_size=3, progress=False, out=kept, resume=True
    )
    assert len(calls) == 3  # the second chunk only
    for got, want in zip(jax.tree.leaves(resumed), jax.tree.leaves(fit)):
        np.testing.assert_array_equal(np.asarray(got), np.concatenate([np.asarray(want)] * 2))
