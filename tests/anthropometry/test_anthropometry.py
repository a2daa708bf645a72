"""Measurements, the population prior, and scaling bodies to measurements (docs/design.md,
section 7)."""

import csv

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.anthropometry._measurements import geometry
from diffbody.anthropometry._prior import ansur2_subjects
from diffbody.anthropometry._scale_to import scaled_body
from diffbody.files._data_files import data_file

N = len(db.SCALE_GROUPS)
FIVE = ("stature", "weightkg", "span", "sittingheight", "hipbreadth")


def p50(sex: str) -> dict[str, float]:
    """ANSUR II medians (m, kg) from data/ansur2_percentiles.csv."""
    with open(data_file("ansur2_percentiles.csv")) as f:
        rows = [r for r in csv.DictReader(line for line in f if not line.startswith("#"))]
    return {
        r["measurement"]: float(r["p50"]) / (1 if r["unit"] == "kg" else 1000)
        for r in rows
        if r["sex"] == sex
    }


@pytest.fixture(scope="module")
def subjects():
    return {sex: ansur2_subjects(sex)[1] for sex in ("male", "female")}


def test_calibration_factors(male50, female50):
    """Each factor is the geometric mean over both median bodies of ANSUR II's median over
    the model's value (`_measurements` docstring); 1 where the model has the landmark."""
    ratios = {}
    for sex, body in (("male", male50), ("female", female50)):
        g, ansur = geometry(body), p50(sex)
        for name, m in db.MEASUREMENTS.items():
            ratios.setdefault(name, []).append(ansur[name] / float(m.model(g)))
    for name, (r_male, r_female) in ratios.items():
        exact = max(abs(r_male - 1), abs(r_female - 1)) < 2e-4
        expected = 1.0 if exact else np.sqrt(r_male * r_female)
        assert db.MEASUREMENTS[name].calibration == pytest.approx(expected, abs=1e-6), name


@pytest.mark.parametrize("sex", ["male", "female"])
def test_default_bodies_measure_what_they_were_built_from(sex, male50, female50):
    """The joints and spheres placed at ANSUR II medians measure those medians exactly; the
    calibrated landmarks within the two sexes' residual disagreement (module docstring)."""
    body = male50 if sex == "male" else female50
    got, ansur = db.measurements(body), p50(sex)
    for name, value in got.items():
        tol = 1e-4 if db.MEASUREMENTS[name].calibration == 1.0 else 0.012
        assert abs(value - ansur[name]) <= tol, (name, value, ansur[name])


def test_measurement_gradients_match_finite_differences(male50):
    """d measurements / d log group scales: forward and reverse mode agree with central
    differences at a scaled body (no extent switches sphere within the step)."""
    x0 = jnp.asarray(np.random.default_rng(0).uniform(-0.05, 0.05, (2, N)))

    def f(x):
        return db.measure(scaled_body(male50, x, 80.0))

    jf = np.asarray(jax.jit(jax.jacfwd(f))(x0)).reshape(-1, 2 * N)
    jr = np.asarray(jax.jit(jax.jacrev(f))(x0)).reshape(-1, 2 * N)
    h = 1e-6
    eye = np.eye(2 * N).reshape(-1, 2, N)
    fd = np.stack([(f(x0 + h * e) - f(x0 - h * e)) / (2 * h) for e in eye], axis=1)
    np.testing.assert_allclose(jf, jr, atol=1e-12)
    np.testing.assert_allclose(jf, fd, atol=1e-7)
    # Every group moves some measurement except those no measurement sees.
    assert np.count_nonzero(np.abs(jf).sum(axis=0) > 0) >= 16


def test_measurements_are_piecewise_linear_in_the_scales(male50):
    """The property the fast solver rests on: lengths = A s within a piece, A the Jacobian."""
    from diffbody.anthropometry._scale_to import _lengths, _linear_model

    s = jnp.asarray(np.random.default_rng(1).uniform(0.95, 1.05, 2 * N))
    A = _linear_model(male50, s)
    np.testing.assert_allclose(A @ s, _lengths(male50, s), rtol=1e-12)


def test_conditional_mean_is_the_linear_regression(subjects):
    """Reference: the plain (non-robust) prior's conditional mean given stature and weight is
    the least-squares regression of the log measurements on the log inputs."""
    values = subjects["female"]
    prior = db.PopulationPrior.fit(values, sex="female", robust=False)
    known = ["stature", "weightkg"]
    c = prior.conditional(known)
    X = np.log(values[:, prior.index(known)])
    Y = np.log(values[:, prior.index(c.unknown)])
    design = np.column_stack([np.ones(len(X)), X])
    coef, *_ = np.linalg.lstsq(design, Y, rcond=None)
    np.testing.assert_allclose(c.unknown_mean(X[:5]), design[:5] @ coef, atol=1e-10)


@pytest.mark.parametrize(
    ("sex", "given"),
    [
        ("female", {"stature": 1.65, "weightkg": 60.0}),
        ("male", {"stature": 1.90, "weightkg": 95.0, "span": 1.98}),
        (
            "male",
            {
                "stature": 1.72,
                "weightkg": 70.0,
                "span": 1.80,
                "sittingheight": 0.90,
                "hipbreadth": 0.33,
            },
        ),
    ],
    ids=["stature-weight", "with-span", "five"],
)
def test_scaling_reproduces_the_given_measurements(sex, given):
    body = db.scale_to(None, given, sex=sex)
    got = db.measurements(body, tuple(given))
    for name, value in given.items():
        assert abs(got[name] - value) < 1e-3, (name, got[name], value)
    # The others follow the population: within 6 standard deviations of the conditional
    # mean, and the body still stands on the ground.
    rest = {n: v for n, v in db.measurements(body).items() if n not in given}
    prior = db.PopulationPrior.ansur2(sex)
    assert not prior.outliers({**given, **rest})
    assert float(jnp.min(db.forward(body, body.rest_pose()).sphere_centers[:, 2])) > 0


def test_no_ansur_subject_is_rejected(subjects):
    """The 6-standard-deviation check never refuses a real person, from stature and weight or
    from the five inputs."""
    for sex, values in subjects.items():
        prior = db.PopulationPrior.ansur2(sex)
        for known in (FIVE[:2], FIVE):
            cols = [db.MEASUREMENT_NAMES.index(k) for k in known]
            z = prior.z_scores(known, values[:, cols])
            assert np.abs(z).max() < 6.0, (sex, known, np.abs(z).max())


@pytest.mark.parametrize(
    ("given", "error", "fragment"),
    [
        ({"height": 1.7}, KeyError, "stature"),
        ({"stature": -1.7}, ValueError, "> 0"),
        ({"stature": 0.0}, ValueError, "> 0"),
        ({"stature": float("nan")}, ValueError, "finite"),
        ({"stature": 1750.0}, ValueError, "millimetres"),
        ({"stature": 2.6}, ValueError, "standard deviations"),
        ({"stature": 1.70, "handlength": 0.40}, ValueError, "handlength = 0.4 m"),
        ({"weightkg": 400.0}, ValueError, "weightkg"),
    ],
)
def test_impossible_measurements_are_refused(given, error, fragment):
    with pytest.raises(error, match=fragment):
        db.scale_to(None, given, sex="male")


def test_sex_and_prior_must_agree():
    with pytest.raises(ValueError, match="sex"):
        db.scale_to(None, {"stature": 1.7})
    with pytest.raises(ValueError, match="differs"):
        db.scale_to(None, {"stature": 1.7}, sex="male", prior=db.PopulationPrior.ansur2("female"))


def test_population_equals_one_at_a_time(subjects):
    values = subjects["male"][:40]
    cols = [db.MEASUREMENT_NAMES.index(k) for k in FIVE]
    out = db.scale_population(FIVE, values[:, cols], sex="male", progress=False, chunk_size=16)
    assert out.reproduced.all() and out.converged.all()
    np.testing.assert_allclose(out.measurements[:, cols], values[:, cols], atol=1e-3)
    one = db.scale_to(None, dict(zip(FIVE, values[7, cols])), sex="male")
    np.testing.assert_allclose(db.measure(one), out.measurements[7], atol=1e-7)
    np.testing.assert_allclose(np.asarray(one.lengths), np.asarray(out.body(7).lengths), atol=1e-9)


def test_percentile_bodies(tmp_path):
    bodies = [db.scale_to_percentile("female", p) for p in (5, 50, 95)]
    stature = [db.measurements(b, ("stature",))["stature"] for b in bodies]
    ansur = p50("female")["stature"]
    assert stature[0] < stature[1] < stature[2] and abs(stature[1] - ansur) < 1e-3
    # A scaled body is a body like any other: it saves, loads back the same, and exports.
    path = db.save_body(bodies[2], tmp_path / "p95.json")
    again = db.load_body(path)
    np.testing.assert_allclose(np.asarray(again.lengths), np.asarray(bodies[2].lengths), atol=1e-12)
    np.testing.assert_allclose(np.asarray(again.masses), np.asarray(bodies[2].masses), atol=1e-12)
    assert again.spine is not None
    assert "<mujoco" in db.export_mjcf(again, tmp_path / "p95.xml").read_text()
    with pytest.raises(ValueError, match="percentile"):
        db.scale_to_percentile("female", 100)


def test_scaling_keeps_symmetry_and_masses(male50):
    body = scaled_body(male50, jnp.full((2, N), 0.1), 90.0)
    assert float(jnp.sum(body.masses)) == pytest.approx(90.0)
    fk = db.forward(body, body.rest_pose())
    c = np.asarray(fk.sphere_centers)
    mirrored = c * np.array([1, -1, 1])
    assert np.abs(np.sort(c, axis=0) - np.sort(mirrored, axis=0)).max() < 1e-12


def test_the_scale_command(tmp_path, capsys):
    from diffbody.cli._main import main

    out = tmp_path / "person.json"
    argv = ["scale", "--sex", "female", "--stature", "1.65", "--weight", "60", "--out", str(out)]
    assert main(argv) == 0
    assert "stature                          1.6500 m *" in capsys.readouterr().out
    body = db.load_body(out)
    assert db.measurements(body, ("stature",))["stature"] == pytest.approx(1.65, abs=1e-4)
    assert main(argv[:4] + ["1650"] + argv[5:]) == 2  # millimetres for metres
    assert "millimetres" in capsys.readouterr().err
