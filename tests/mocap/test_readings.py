"""Tape or caliper readings beside the static trial (`scale_and_register(measured=)`): a
reading pulls the scaled body's measurement toward it by its standard deviation, a tight one
is met, every set of readings shares one compiled fit, and bad readings are refused by name.
On the shipped OpenSim example, in float32 as a user runs it."""

import argparse

import jax
import pytest
from compiles import counted_compiles

import diffbody as db
from diffbody.cli._mocap import readings
from diffbody.files._data_files import data_file
from diffbody.mocap._grades import readings_report
from diffbody.mocap._tape_readings import TAPE_SD
from diffbody.mocap._trials_summary import header_fields, summary_changes

# m: the shipped subject's stature, as OpenSim's scale set-up gives it (data/mocap/README.md).
SUBJECT_STATURE = 1.803


@pytest.fixture(scope="module")
def fits():
    """Without readings; with the stature read 3 cm over the fit's own (5 mm); with the
    stature and the span read to 0.1 mm (the compiles of that second set counted)."""
    with jax.enable_x64(False):
        body = db.load_body(variant="male50")
        static = db.read_trc(data_file("mocap/subject01_static.trc"))
        markers = db.load_markerset("opensim-gait", body)

        def fit(**readings):
            return db.scale_and_register(body, static, markers, **readings)

        base = fit()
        read = db.measurements(base.body, ("stature",))["stature"] + 0.03
        loose = fit(measured={"stature": read})
        tight_readings = {"stature": read, "span": 1.80}
        with counted_compiles() as compiles:
            tight = fit(measured=tight_readings, measured_sd=1e-4)
            taped = fit(measured={"stature": SUBJECT_STATURE})
    return base, loose, tight, read, tight_readings, compiles, taped


def test_a_reading_pulls_the_measurement_toward_it(fits):
    """Read 3 cm over the markers' and the prior's stature: the fit moves toward the
    reading, past halfway, and ends within 3 of the reading's standard deviations of it."""
    base, loose, _, read, _, _, _ = fits
    before = db.measurements(base.body, ("stature",))["stature"]
    after = db.measurements(loose.body, ("stature",))["stature"]
    assert loose.converged
    assert before + 0.015 < after <= read + 1e-4
    assert read - after <= 3 * TAPE_SD


def test_tight_readings_are_met_on_one_program(fits):
    """Readings to 0.1 mm are met to a millimetre, each, and a second set of readings (other
    names, other values, another standard deviation) compiles nothing new."""
    _, _, tight, _, tight_readings, compiles, _ = fits
    fitted = db.measurements(tight.body, tuple(tight_readings))
    for name, value in tight_readings.items():
        assert abs(fitted[name] - value) < 1e-3, name
    assert compiles == []


def test_the_subject_s_own_stature_is_met(fits):
    """The shipped subject's tape stature (1.803 m) taken with the markers: the scaled body
    measures it within 2 mm (1.804 m in float32), its fit converged."""
    taped = fits[-1]
    assert taped.converged
    fitted = db.measurements(taped.body, ("stature",))["stature"]
    assert abs(fitted - SUBJECT_STATURE) < 2e-3
    assert f"{fitted:.3f}" == "1.804"


@pytest.mark.parametrize(
    "measured, sd, error, words",
    [
        ({"statue": 1.8}, TAPE_SD, KeyError, "stature"),
        ({"weightkg": 80.0}, TAPE_SD, ValueError, "not a length"),
        ({"stature": 1780.0}, TAPE_SD, ValueError, "give metres"),
        ({"stature": float("nan")}, TAPE_SD, ValueError, "'stature'"),
        ({"span": -1.8}, TAPE_SD, ValueError, "'span'"),
        ({"stature": "tall"}, TAPE_SD, ValueError, "number of metres"),
        ({"stature": 1.8}, 0.0, ValueError, "measured_sd"),
        ({"stature": 1.8}, {"stature": float("inf")}, ValueError, "measured_sd"),
        ([("stature", 1.8)], TAPE_SD, TypeError, "map measurement names"),
    ],
)
def test_bad_readings_are_refused_by_name(measured, sd, error, words):
    body = db.load_body(variant="male50")
    static = db.read_trc(data_file("mocap/subject01_static.trc"))
    markers = db.load_markerset("opensim-gait", body)
    with pytest.raises(error, match=words):
        db.scale_and_register(body, static, markers, measured=measured, measured_sd=sd)


def test_the_command_line_reads_its_readings():
    """--measure NAME=METRES (repeated) and --measure-sd become the fit's keywords; a
    reading without '=' is refused with the form to use; the report gives read, fitted and
    their difference."""
    args = argparse.Namespace(measure=["stature=1.78", " span = 1.8"], measure_sd=0.002)
    assert readings(args) == {"measured": {"stature": 1.78, "span": 1.8}, "measured_sd": 0.002}
    assert readings(argparse.Namespace(measure=[], measure_sd=None)) == {}
    with pytest.raises(ValueError, match="NAME=METRES"):
        readings(argparse.Namespace(measure=["stature"], measure_sd=None))
    body = db.load_body(variant="male50")
    stature = db.measurements(body, ("stature",))["stature"]
    text = readings_report(body, {"stature": stature - 0.01})
    assert f"fitted {stature:.3f} m (+10.0 mm)" in text


def test_a_folder_of_trials_records_its_readings():
    """The summary's header names the readings, a resume with others is refused in words,
    and a summary from before readings were recorded resumes a run without any."""
    body = db.load_body(variant="male50")
    static = data_file("mocap/subject01_static.trc")
    markers = db.load_markerset("opensim-gait", body)

    def header(readings):
        # `fit_trials` adds the model its .mot files drive.
        return {"opensim-model": "gait2354"} | dict(
            header_fields(
                body,
                static,
                markers,
                None,
                keep_zeros=False,
                axes=None,
                prior=True,
                time=None,
                readings=readings,
            )
        )

    given = {"measured": {"stature": 1.78}, "measured_sd": 0.002}
    read, unread = header(given), header(None)
    assert read["measured"] == "stature=1.78 sd=0.002" and unread["measured"] == "(none)"
    assert (
        "the readings (--measure, --measure-sd) changed from stature=1.78 sd=0.002 to "
        "(none)" in summary_changes(read, unread)
    )
    older = {k: v for k, v in unread.items() if k != "measured"}
    assert not any("readings" in c for c in summary_changes(older, unread))
    # Before the velocity term: a summary without the field was fitted without it.
    assert unread["velocity"] == "on"
    before = {k: v for k, v in unread.items() if k != "velocity"}
    velocity = "the motion fits' velocity term (--no-velocity) changed from off to on"
    assert velocity in summary_changes(before, unread)
    assert not any("velocity" in c for c in summary_changes(before, unread | {"velocity": "off"}))
