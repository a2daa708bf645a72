"""Strict test configuration: float64 everywhere, shared bodies and compiled functions."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

import diffbody as db  # noqa: E402

settings.register_profile(
    "diffbody",
    deadline=None,
    max_examples=60,
    derandomize=True,  # reproducible in CI
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("diffbody")


@pytest.fixture(scope="session")
def male50() -> db.Body:
    return db.load_body(variant="male50")


@pytest.fixture(scope="session")
def female50() -> db.Body:
    return db.load_body(variant="female50")


@pytest.fixture(scope="session")
def fk_male50(male50):
    """forward for the male50 body, compiled once for the whole session."""
    return jax.jit(lambda pose: db.forward(male50, pose))
