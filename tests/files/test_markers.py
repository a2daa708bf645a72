"""Marker files (TRC, C3D) and marker sets: reading against the raw text and against OpenSim's
own reader, exact write/read round trips, clear errors on bad files and bad sets, matching a
set to a trial, and marker kinematics against `forward`'s sphere centres and features."""

import json
import math
import warnings
import xml.etree.ElementTree as ET

import equinox as eqx
import hypothesis.strategies as st
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given

import diffbody as db
from diffbody._body import rest_geometry
from diffbody.files._data_files import data_file
from diffbody.files._marker_files import read_c3d, read_markers
from diffbody.files._marker_trial import LAB_AXES, MarkerFileError, MarkerTrial
from diffbody.files._markerset_file import MarkerSet, load_markerset
from diffbody.files._trc import read_trc, write_trc
from diffbody.mocap._markerset import MarkerWarning, match_markers, scale_offsets, world_markers

STATIC = data_file("mocap/subject01_static.trc")
WALK = data_file("mocap/subject01_walk1.trc")
STATIC_ONLY = tuple(f"{s}.{j}.{m}" for s in "RL" for j in ("Knee", "Ankle") for m in ("Lat", "Med"))


@pytest.fixture(scope="module")
def static():
    return read_trc(STATIC)


@pytest.fixture(scope="module")
def walk():
    return read_trc(WALK)


@pytest.fixture(scope="module")
def gait(male50):
    return load_markerset("opensim-gait", male50)


# --- reading the shipped trials ------------------------------------------------------------------
def test_read_static_against_raw_text(static):
    lines = STATIC.read_text().splitlines()
    names = [c for c in lines[3].split("\t")[2:] if c]
    assert static.positions.shape == (300, 49, 3)
    assert static.names == tuple(names) and len(names) == 49
    assert static.rate == 60.0 and static.source == str(STATIC)
    assert not np.isnan(static.positions).any()
    # Frame 2 (line 8), marker 'L.ASIS' (cells 6-8): lab (X, Y, Z) mm -> world (X, -Z, Y) m.
    cells = lines[7].split("\t")
    X, Y, Z = (float(c) / 1000 for c in cells[5:8])
    assert static.times[1] == float(cells[1]) == 0.017
    np.testing.assert_allclose(static.marker("L.ASIS")[1], [X, -Z, Y], rtol=1e-15)
    assert static.marker("L.ASIS")[1, 1] > static.marker("R.ASIS")[1, 1]  # left is +y


def test_read_walk(walk):
    assert walk.positions.shape == (151, 41, 3)
    assert set(STATIC_ONLY).isdisjoint(walk.names)
    assert walk.times[0] == 0.0 and walk.times[-1] == 2.5
    ik = walk.between(0.4, 1.6)  # OpenSim's IK range (subject01_Setup_IK.xml)
    assert ik.n_frames == 73 and ik.times[0] == 0.4 and ik.times[-1] == 1.6
    # On a treadmill, facing +X, upright: toes ahead of heels, the sacrum behind the ASIS,
    # the head the highest marker, in every frame.
    for side in "RL":
        assert np.all(walk.marker(f"{side}.Toe.Tip")[:, 0] > walk.marker(f"{side}.Heel")[:, 0])
        assert np.all(walk.marker(f"{side}.ASIS")[:, 0] > walk.marker("V.Sacral")[:, 0])
    assert np.all(walk.marker("Top.Head")[:, 2] == walk.positions[:, :, 2].max(axis=1))


@pytest.fixture(scope="module")
def osim():
    """OpenSim, the reference reader: a test requirement (the `opensim` extra), never skipped."""
    try:
        import opensim
    except ImportError as error:
        pytest.fail(f"OpenSim is needed by this test: pip install -e '.[test,opensim]' ({error})")
    return opensim


def test_opensim_reads_the_same(static, osim):
    """OpenSim's own TRC reader (a reference implementation) gives the same numbers."""
    table = osim.TimeSeriesTableVec3(str(STATIC))
    assert tuple(table.getColumnLabels()) == static.names
    rows = [0, 150, 299]
    lab = np.array([[table.getRowAtIndex(r)[m].to_numpy() for m in range(49)] for r in rows])
    world = lab[..., [0, 2, 1]] * [1, -1, 1] / 1000
    np.testing.assert_allclose(static.positions[rows], world, rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(
        np.asarray(table.getIndependentColumn())[rows], static.times[rows]
    )


def test_trial_views(static):
    names = ("Top.Head", "R.ASIS")
    sub = static.select(names)
    assert sub.names == names
    np.testing.assert_array_equal(sub.positions[:, 1], static.marker("R.ASIS"))
    with pytest.raises(KeyError, match="Did you mean 'R.ASIS'"):
        static.marker("R.ASlS")
    one = static.mean_frame()
    assert one.n_frames == 1 and one.times[0] == pytest.approx(static.times.mean())
    np.testing.assert_allclose(one.positions[0], static.positions.mean(axis=0), rtol=1e-14)


def test_mean_frame_skips_gaps():
    P = np.arange(24.0).reshape(4, 2, 3)
    P[1, 0] = np.nan
    P[:, 1] = np.nan  # never seen: stays NaN, without a warning
    trial = MarkerTrial(("a", "b"), np.arange(4.0), P, 1.0, "test")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mean = trial.mean_frame().positions[0]
    np.testing.assert_allclose(mean[0], P[[0, 2, 3], 0].mean(axis=0))
    assert np.isnan(mean[1]).all()


# --- axes ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(LAB_AXES))
def test_lab_axes_are_rotations(name):
    R = LAB_AXES[name]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_opensim_axes_map():
    R = LAB_AXES["opensim"]
    forward, up, right = np.eye(3)  # OpenSim lab X, Y, Z
    np.testing.assert_array_equal(R @ forward, [1, 0, 0])
    np.testing.assert_array_equal(R @ up, [0, 0, 1])
    np.testing.assert_array_equal(R @ right, [0, -1, 0])  # the subject's right is world -y


def test_axes_by_matrix(static, tmp_path):
    yaw = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # lab X -> world y
    turned = read_trc(STATIC, axes=yaw @ LAB_AXES["opensim"])
    np.testing.assert_allclose(turned.positions, static.positions @ yaw.T, atol=1e-15)
    with pytest.raises(ValueError, match="reflection"):
        read_trc(STATIC, axes=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="rotation matrix"):
        read_trc(STATIC, axes=np.ones((3, 3)))
    with pytest.raises(KeyError, match="Did you mean 'z-up'"):
        read_trc(STATIC, axes="z_up")


# --- round trip ----------------------------------------------------------------------------------
NAME = st.text("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._- ", min_size=1)


@st.composite
def trials(draw):
    n_frames = draw(st.integers(0, 5))
    names = draw(st.lists(NAME.map(str.strip).filter(bool), min_size=1, max_size=4, unique=True))
    finite = st.floats(allow_nan=False, allow_infinity=False)
    values = draw(
        st.lists(finite, min_size=n_frames * len(names) * 3, max_size=n_frames * len(names) * 3)
    )
    P = np.reshape(np.array(values, float), (n_frames, len(names), 3))
    gaps = draw(
        st.lists(st.booleans(), min_size=P.shape[0] * P.shape[1], max_size=P.shape[0] * P.shape[1])
    )
    P[np.reshape(np.array(gaps, bool), P.shape[:2])] = np.nan
    times = np.array(draw(st.lists(finite, min_size=n_frames, max_size=n_frames)), float)
    rate = draw(st.floats(1e-3, 1e5))
    return tuple(names), times, P, rate  # the MarkerTrial is built in the test: its
    # runtime type checks sample the random module, which strategies must not touch


@pytest.fixture(scope="module")
def round_trip_file(tmp_path_factory):
    return tmp_path_factory.mktemp("trc") / "trial.trc"  # rewritten by every example


@given(
    trial=trials(), units=st.sampled_from(["mm", "cm", "m"]), axes=st.sampled_from(sorted(LAB_AXES))
)
def test_write_read_round_trip_is_exact(round_trip_file, trial, units, axes):
    path = round_trip_file
    trial = MarkerTrial(*trial, source="drawn")
    write_trc(path, trial, axes=axes, units=units)
    # A marker drawn at exactly (0, 0, 0) is written as such: read it as a position.
    back = read_trc(path, axes=axes, zero_is_gap=False)
    assert back.names == trial.names and back.rate == trial.rate
    np.testing.assert_array_equal(back.times, trial.times)
    np.testing.assert_array_equal(back.positions, trial.positions)  # NaN where NaN


def test_write_then_opensim_reads_gaps(tmp_path, osim):
    """OpenSim reads what write_trc writes, gaps included."""
    P = np.random.default_rng(0).normal(size=(3, 2, 3))
    P[1, 0] = np.nan
    trial = MarkerTrial(("a", "b"), np.array([0.0, 0.5, 1.0]), P, 2.0, "test")
    write_trc(tmp_path / "gaps.trc", trial)
    table = osim.TimeSeriesTableVec3(str(tmp_path / "gaps.trc"))
    lab = np.array([[table.getRowAtIndex(r)[m].to_numpy() for m in range(2)] for r in range(3)])
    np.testing.assert_allclose(lab[..., [0, 2, 1]] * [1, -1, 1] / 1000, P, rtol=1e-14)
    assert np.isnan(lab[1, 0]).all() and not np.isnan(lab[1, 1]).any()


def test_write_rejects_what_trc_cannot_hold(tmp_path):
    P = np.zeros((2, 1, 3))
    trial = MarkerTrial(("a",), np.array([0.0, 1.0]), P, 1.0, "test")
    with pytest.raises(ValueError, match="unknown units 'in'"):
        write_trc(tmp_path / "t.trc", trial, units="in")
    P[1, 0, 2] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        write_trc(tmp_path / "t.trc", MarkerTrial(("a",), trial.times, P, 1.0, "test"))
    with pytest.raises(ValueError, match="cannot be written"):
        write_trc(
            tmp_path / "t.trc", MarkerTrial(("a\tb",), trial.times, np.zeros_like(P), 1.0, "test")
        )
    with pytest.raises(ValueError, match="given twice"):
        MarkerTrial(("a", "a"), trial.times, np.zeros((2, 2, 3)), 1.0, "test")
    with pytest.raises(ValueError, match=r"\(n_frames, n_markers, 3\) = \(2, 2, 3\)"):
        MarkerTrial(("a", "b"), trial.times, P, 1.0, "test")


# --- gaps and bad files --------------------------------------------------------------------------
HEADER = [
    "PathFileType\t4\t(X/Y/Z)\tt.trc",
    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits",
    "100\t100\t3\t2\tmm",
    "Frame#\tTime\tA\t\t\tB\t\t",
    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2",
    "",
]
ROWS = [
    "1\t0.00\t1\t2\t3\t4\t5\t6",
    "2\t0.01\t1\t2\t3\t\t\t",  # B missing: empty cells
    "3\t0.02\t\t2\t3\t4\t5",  # A partly missing, B cut short: both missing
]


def _trc(tmp_path, header=HEADER, rows=ROWS, name="t.trc"):
    path = tmp_path / name
    path.write_text("\n".join(header + rows) + "\n")
    return path


def test_gaps_are_nan(tmp_path):
    trial = read_trc(_trc(tmp_path), axes="z-up")
    np.testing.assert_array_equal(trial.positions[0], [[1e-3, 2e-3, 3e-3], [4e-3, 5e-3, 6e-3]])
    assert not np.isnan(trial.positions[1, 0]).any() and np.isnan(trial.positions[1, 1]).all()
    assert np.isnan(trial.positions[2]).all()
    np.testing.assert_array_equal(trial.present, [[True, True], [True, False], [False, False]])


def _replace(lines, i, text):
    return lines[:i] + [text] + lines[i + 1 :]


BAD_FILES = {
    "letter in a cell": (
        HEADER,
        _replace(ROWS, 1, "2\t0.01\t1\t2O\t3\t4\t5\t6"),
        ["line 8, column 4", "A Y", "'2O'", "number"],
    ),
    "time not a number": (
        HEADER,
        _replace(ROWS, 0, "1\tt0\t1\t2\t3\t4\t5\t6"),
        ["line 7, column 2"],
    ),
    "time missing": (HEADER, _replace(ROWS, 0, "1\t\t1\t2\t3\t4\t5\t6"), ["line 7", "Time"]),
    "infinite value": (
        HEADER,
        _replace(ROWS, 0, "1\t0\t1\tinf\t3\t4\t5\t6"),
        ["column 4", "'inf'"],
    ),
    "extra cell": (HEADER, _replace(ROWS, 0, "1\t0\t1\t2\t3\t4\t5\t6\t7"), ["line 7", "column 9"]),
    "truncated header": (HEADER[:3], [], ["line 4", "header ends after 3 line(s)"]),
    "not a TRC file": (_replace(HEADER, 0, "Frame#\tTime"), ROWS, ["line 1", "PathFileType"]),
    "NumMarkers mismatch": (
        _replace(HEADER, 2, "100\t100\t3\t3\tmm"),
        ROWS,
        ["line 4", "2 marker names", "NumMarkers", "says 3"],
    ),
    "NumFrames mismatch": (
        _replace(HEADER, 2, "100\t100\t4\t2\tmm"),
        ROWS,
        ["line 3", "NumFrames", "says 4 frames", "3 rows (lines 7-9)"],
    ),
    "unknown units": (
        _replace(HEADER, 2, "100\t100\t3\t2\tinch"),
        ROWS,
        ["line 3, column 5", "'inch'", "mm, cm, m"],
    ),
    "Units not named": (
        _replace(HEADER, 1, "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnit"),
        ROWS,
        ["line 2", "'Units'"],
    ),
    "header value missing": (
        _replace(HEADER, 2, "100\t100\t3\t2"),
        ROWS,
        ["line 3", "4 header values"],
    ),
    "bad rate": (_replace(HEADER, 2, "0\t100\t3\t2\tmm"), ROWS, ["line 3, column 1", "DataRate"]),
    "coordinate labels": (
        _replace(HEADER, 4, "\t\tX1\tY1\tZ1"),
        ROWS,
        ["line 5", "expected 3 per"],
    ),
    "duplicate names": (
        _replace(HEADER, 3, "Frame#\tTime\tA\t\t\tA\t\t"),
        ROWS,
        ["line 4", "twice"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_trc_fails_clearly(tmp_path, case):
    header, rows, expected = BAD_FILES[case]
    path = _trc(tmp_path, header, rows, name="bad.trc")
    with pytest.raises(MarkerFileError) as err:
        read_trc(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    for text in expected:
        assert text in message


def test_read_markers_by_extension(tmp_path, static):
    np.testing.assert_array_equal(read_markers(STATIC).positions, static.positions)
    with pytest.raises(MarkerFileError, match=r"'\.csv'.*\.trc and \.c3d"):
        read_markers(tmp_path / "trial.csv")
    with pytest.raises(FileNotFoundError, match="no such marker file"):
        read_trc(tmp_path / "missing.trc")


def test_c3d_round_trip(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    rng = np.random.default_rng(1)
    points = np.ones((4, 2, 5))
    points[:3] = rng.uniform(-1000, 1000, (3, 2, 5))
    points[:3, 1, 2] = np.nan  # marker B unseen in frame 3
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ("A", "B")
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["data"]["points"] = points
    c3d.write(str(tmp_path / "t.c3d"))
    trial = read_markers(tmp_path / "t.c3d", axes="z-up")
    assert trial.names == ("A", "B") and trial.rate == 100.0
    np.testing.assert_allclose(trial.times, np.arange(5) / 100)
    expected = np.transpose(points[:3], (2, 1, 0)) / 1000
    np.testing.assert_allclose(trial.positions, expected, atol=1e-7)  # C3D stores float32
    assert np.isnan(trial.positions[2, 1]).all() and not np.isnan(trial.positions[2, 0]).any()
    with pytest.raises(MarkerFileError, match="ezc3d cannot read"):
        read_c3d(_trc(tmp_path))


def test_c3d_without_ezc3d(monkeypatch, tmp_path):
    monkeypatch.setitem(__import__("sys").modules, "ezc3d", None)
    with pytest.raises(ImportError, match=r"pip install diffbody\[c3d\]"):
        read_c3d(tmp_path / "t.c3d")


# --- the shipped marker set ----------------------------------------------------------------------
ANATOMICAL = {
    "ASIS",
    "Sacral",
    "Knee",
    "Ankle",
    "Heel",
    "Tip",
    "Acromium",
    "Elbow",
    "Wrist",
    "Temple",
    "Head",
    "Sternum",
}


def test_shipped_set(male50, gait, static):
    assert gait.names == static.names  # all 49, in the static trial's order
    for name, kind in zip(gait.names, gait.kinds):
        parts = set(name.split("."))
        assert kind == ("anatomical" if parts & ANATOMICAL else "tracking"), name
    tol = dict(zip(gait.names, np.asarray(gait.tolerances)))
    assert all(0.005 <= tol[n] <= 0.01 for n, k in zip(gait.names, gait.kinds) if k == "anatomical")
    assert all(0.02 <= tol[n] <= 0.03 for n, k in zip(gait.names, gait.kinds) if k == "tracking")
    # IK weights: OpenSim's setup where it lists the marker, 1 otherwise.
    setup = ET.parse(data_file("mocap/subject01_Setup_IK.xml")).getroot()
    listed = {t.get("name"): float(t.findtext("weight")) for t in setup.iter("IKMarkerTask")}
    assert len(listed) == 31
    expected = [listed.get(n, 1.0) for n in gait.names]
    np.testing.assert_array_equal(np.asarray(gait.weights), expected)
    segments = [male50.segment_names[s] for s in gait.segments]
    for name, seg in zip(gait.names, segments):
        side = {"R": "right_", "L": "left_"}.get(name.split(".")[0])
        if seg.startswith(("left_", "right_")):  # never a left marker on a right segment
            assert seg.startswith(side), (name, seg)


def _rest_markers(body, markerset):
    """Standard-position world markers without JAX kinematics: every frame is the segment's
    standard cross of axes and no twist."""
    joints, _ = rest_geometry(body)
    seg = np.asarray(markerset.segments)
    R = np.asarray(body.R_socket_rest)[seg]
    prox = joints[np.asarray(body.proximal_joint)[seg]]
    return prox + np.einsum("kij,kj->ki", R, np.asarray(markerset.offsets))


def _limb(name: str) -> str:
    return "arm" if "arm" in name or "hand" in name else "leg" if name[-5:] in LEGS else ""


LEGS = ("thigh", "shank", "_foot")


def test_shipped_set_sits_on_the_skin(male50, female50):
    """In the standard position every marker lies outside all spheres and within 2 cm of
    the skin, left markers on the left, for both default bodies. (The hands rest against the
    thighs there: arm markers are not measured against leg spheres, nor leg markers against
    arm spheres.)"""
    for body in (male50, female50):
        markers = load_markerset("opensim-gait", body)
        p = _rest_markers(body, markers)
        _, centers = rest_geometry(body)
        gap = np.linalg.norm(p[:, None] - centers[None], axis=-1) - np.asarray(body.sphere_radii)
        limb = np.array([_limb(body.segment_names[s]) for s in body.sphere_segment])
        for k, name in enumerate(markers.names):
            own = _limb(body.segment_names[markers.segments[k]])
            apart = {"arm": "leg", "leg": "arm"}.get(own, "none")
            clearance = gap[k, limb != apart].min()
            assert 0.003 < clearance < 0.02, (body.name, name, clearance)
            y = p[k, 1]
            assert {"R": y < 0, "L": y > 0}.get(name[0], abs(y) < 1e-9), name


def test_shipped_set_matches_the_static_trial(male50, static):
    """The lower body's markers, the default body scaled to the subject's stature in its
    standard position, against the static trial's mean (pelvis faces +X): heights within
    6.5 cm, and the distances that scale the legs within 3 cm."""
    gait = load_markerset("opensim-gait", male50)
    k = 1.8034 / 1.755  # the subject's stature (OpenSim's scale setup) over the body's
    a, r = jnp.full(male50.n_segments, k), jnp.ones(male50.n_segments)
    body = db.scale_body(male50, a, r)
    model = dict(zip(gait.names, _rest_markers(body, scale_offsets(gait, male50, a, r))))
    trial = dict(zip(static.names, static.mean_frame().positions[0]))
    legs = [n for n in gait.names if not any(s in n for s in ("Acrom", "Bicep", "Elbow", "Wrist"))]
    heights = np.array([model[n][2] - trial[n][2] for n in legs])
    assert np.abs(heights).max() < 0.065, dict(zip(legs, heights.round(3)))
    for a_, b_ in [
        ("R.ASIS", "L.ASIS"),
        ("R.ASIS", "V.Sacral"),
        ("R.ASIS", "R.Knee.Lat"),
        ("L.ASIS", "L.Knee.Lat"),
        ("R.Knee.Lat", "R.Ankle.Lat"),
        ("L.Knee.Lat", "L.Ankle.Lat"),
        ("R.Heel", "R.Toe.Tip"),
        ("L.Heel", "L.Toe.Tip"),
        ("R.Toe.Lat", "R.Toe.Med"),
    ]:
        d_model = np.linalg.norm(model[a_] - model[b_])
        d_trial = np.linalg.norm(trial[a_] - trial[b_])
        assert abs(d_model - d_trial) < 0.03, (a_, b_, d_model, d_trial)


# --- bad marker sets -----------------------------------------------------------------------------
def _doc(**marker):
    entry = {
        "name": "M",
        "segment": "left_thigh",
        "sphere_surface": [0, 1, 0],
        "along": 0.5,
        "kind": "tracking",
        "tolerance": 0.02,
        "weight": 1,
    }
    entry.update(marker)
    return {
        "schema": "diffbody.markerset/1",
        "name": "test",
        "axes": "standard",
        "markers": [entry],
    }


def _drop(keys, **marker):
    doc = _doc(**marker)
    for key in keys.split():
        del doc["markers"][0][key]
    return doc


BAD_SETS = {
    "unknown segment": (_doc(segment="left_thgh"), "segment", "Did you mean 'left_thigh'"),
    "whole body": (_doc(segment="whole_body"), "segment", "unknown segment 'whole_body'"),
    "unknown feature": (
        _drop("sphere_surface along", feature="left_thigh.kne"),
        "feature",
        "Did you mean 'left_thigh.knee'",
    ),
    "zero tolerance": (_doc(tolerance=0), "tolerance", "must be > 0"),
    "negative tolerance": (_doc(tolerance=-0.01), "tolerance", "must be > 0"),
    "tolerance in mm": (_doc(tolerance=5), "tolerance", "mm written as m"),
    "zero weight": (_doc(weight=0), "weight", "must be > 0"),
    "bad kind": (_doc(kind="bony"), "kind", "'anatomical'"),
    "two placements": (_doc(offset=[0, 0, 0]), None, "exactly one placement"),
    "along without surface": (_drop("sphere_surface", offset=[0, 0, 0]), "along", "remove it"),
    "no placement": (_drop("sphere_surface"), None, "found none"),
    "along missing": (_drop("along"), "along", "fraction of the segment's length"),
    "along outside": (_doc(along=1.5), "along", "must lie in [0, 1]"),
    "ray misses": (
        _doc(segment="left_foot", along=1.0, sphere_surface=[0, 0, 1]),
        "sphere_surface",
        "meets none",
    ),
    "zero direction": (_doc(sphere_surface=[0, 0, 0]), "sphere_surface", "non-zero direction"),
    "unknown field": (_doc(wieght=1), "wieght", "unknown field"),
    "shift with offset": (
        _drop("sphere_surface along", offset=[0, 0, 0], shift=[0, 0, 0]),
        "shift",
        "takes no shift",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_SETS))
def test_bad_marker_set_fails_clearly(tmp_path, male50, case):
    doc, field, expected = BAD_SETS[case]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(MarkerFileError) as err:
        load_markerset(path, male50)
    message = str(err.value)
    assert message.startswith(f"{path}: marker 'M' (markers[0])")
    if field:
        assert f"field {field!r}" in message
    assert expected in message, message


def test_bad_marker_set_top_level(tmp_path, male50):
    doc = _doc()
    doc["markers"].append(dict(doc["markers"][0]))  # the same name twice
    path = tmp_path / "twice.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(MarkerFileError, match=r"markers\[1\]\), field 'name': given twice"):
        load_markerset(path, male50)
    path.write_text(json.dumps({**_doc(), "schema": "diffbody.markerset/2"}))
    with pytest.raises(MarkerFileError, match="top level, field 'schema'"):
        load_markerset(path, male50)
    path.write_text("{")
    with pytest.raises(MarkerFileError, match="not valid JSON"):
        load_markerset(path, male50)
    with pytest.raises(KeyError, match="Did you mean 'opensim-gait'"):
        load_markerset("opensim_gait", male50)


def test_placements(tmp_path, male50, compiled):
    """Each placement lands where its definition says, in both axes conventions."""
    knee = male50.feature_index("left_thigh.knee")
    doc = {
        "schema": "diffbody.markerset/1",
        "name": "test",
        "marker_radius": 0.01,
        "markers": [
            {
                "name": "F",
                "segment": "left_shank",
                "feature": "left_thigh.knee",
                "shift": [0, 0, 0.02],
            },
            {"name": "S", "segment": "left_thigh", "sphere_surface": [0, -1, 0], "along": 0.0},
            {"name": "O", "segment": "left_thigh", "offset": [0.1, 0.2, 0.3]},
        ],
    }
    for m in doc["markers"]:
        m.update(kind="tracking", tolerance=0.02, weight=1)
    path = tmp_path / "set.json"
    path.write_text(json.dumps(doc))
    seg = load_markerset(path, male50)
    path.write_text(json.dumps({**doc, "axes": "standard"}))
    std = load_markerset(path, male50)
    p_seg, p_std = _rest_markers(male50, seg), _rest_markers(male50, std)
    kin = compiled[0](male50, male50.rest_pose())
    joints, _ = rest_geometry(male50)
    hip = joints[male50.joint_index("left_hip")]
    R_thigh = np.asarray(male50.R_socket_rest[male50.segment_index("left_thigh")])
    normal = np.asarray(kin.feature_normals[knee])
    knee_point = np.asarray(kin.feature_points[knee])
    # Feature: the knee's front point, out by the radius, then 2 cm along the shank's Z (down)
    # in segment axes, or up in standard axes.
    np.testing.assert_allclose(p_seg[0], knee_point + 0.01 * normal + [0, 0, -0.02], atol=1e-12)
    np.testing.assert_allclose(p_std[0], knee_point + 0.01 * normal + [0, 0, 0.02], atol=1e-12)
    # Surface: from the hip joint along the thigh's -Y (the body's left) to the outermost
    # sphere there (the hip sphere of radius r, centred on the joint), plus the radius.
    r = float(male50.sphere_radii[male50.segment_spheres("left_thigh")[0]])
    np.testing.assert_allclose(p_seg[1], hip + [0, r + 0.01, 0], atol=1e-12)
    np.testing.assert_allclose(p_std[1], hip + [0, -(r + 0.01), 0], atol=1e-12)
    np.testing.assert_allclose(p_seg[2], hip + R_thigh @ [0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(p_std[2], hip + [0.1, 0.2, 0.3], atol=1e-12)


# --- matching ------------------------------------------------------------------------------------
def test_match_walk_warns_about_static_only_markers(gait, walk):
    with pytest.warns(MarkerWarning) as record:
        markers, trial = match_markers(gait, walk)
    assert len(record) == 1
    message = str(record[0].message)
    assert all(name in message for name in STATIC_ONLY) and "8 marker(s)" in message
    assert markers.names == trial.names == tuple(n for n in gait.names if n not in STATIC_ONLY)
    np.testing.assert_array_equal(trial.positions, walk.select(markers.names).positions)
    np.testing.assert_array_equal(markers.offsets, gait.select(markers.names).offsets)


def test_match_lists_unmapped_markers(gait, static):
    extra = MarkerTrial(
        static.names + ("Cluster.1", "Cluster.2"),
        static.times,
        np.concatenate([static.positions, np.zeros((static.n_frames, 2, 3))], axis=1),
        static.rate,
        "extra.trc",
    )
    with pytest.warns(MarkerWarning, match=r"2 marker\(s\).*does not map.*Cluster\.1, Cluster\.2"):
        markers, trial = match_markers(gait, extra)
    assert markers.names == trial.names == gait.names
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        match_markers(gait, static)  # the same markers: no warning
    with pytest.raises(ValueError, match="share no marker"), pytest.warns(MarkerWarning):
        match_markers(gait, extra.select(["Cluster.1"]))


# --- kinematics ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def on_spheres(male50):
    """A hand-made set with one marker at a sphere centre of every segment that has
    spheres (the most distal one: it turns most with the twist), and markers at the feature
    points whose direction has no Z part (so the point's z, which sets its turn, is its
    sphere origin's)."""
    seg = np.asarray(male50.sphere_segment)
    spheres = [int(np.flatnonzero(seg == s)[-1]) for s in np.unique(seg)]
    dirs = np.asarray(male50.feature_directions)
    features = [int(f) for f in np.flatnonzero(np.abs(dirs[:, 2]) < 1e-12)]
    f_sph = np.asarray(male50.feature_sphere)[features]
    origins = np.asarray(male50.sphere_origins)
    radii = np.asarray(male50.sphere_radii)
    offsets = np.concatenate(
        [origins[spheres], origins[f_sph] + radii[f_sph, None] * dirs[features]]
    )
    n = len(offsets)
    markers = MarkerSet(
        name="on-spheres",
        source="test",
        names=tuple(f"m{i}" for i in range(n)),
        segments=tuple(int(s) for s in seg[np.concatenate([spheres, f_sph])]),
        kinds=("tracking",) * n,
        offsets=jnp.asarray(offsets),
        tolerances=jnp.full(n, 0.01),
        weights=jnp.ones(n),
    )
    return markers, np.asarray(spheres), np.asarray(features)


@pytest.fixture(scope="module")
def compiled():
    return eqx.filter_jit(db.forward), eqx.filter_jit(world_markers)


def _random_pose(body, rng):
    n = body.n_segments
    angles = np.stack(
        [
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(0.2, np.pi - 0.2, n),
            rng.uniform(-1.5, 1.5, n),
        ],
        axis=-1,
    )
    return db.Pose(position=jnp.asarray(rng.normal(size=3)), angles=jnp.asarray(angles))


def test_world_markers_match_forward(male50, on_spheres, compiled):
    fk, wm = compiled
    markers, spheres, features = on_spheres
    rng = np.random.default_rng(7)
    n_sph = len(spheres)
    for _ in range(3):
        pose = _random_pose(male50, rng)
        kin = fk(male50, pose)
        p = np.asarray(wm(male50, pose, markers))
        np.testing.assert_allclose(p[:n_sph], kin.sphere_centers[spheres], atol=1e-12)
        np.testing.assert_allclose(p[n_sph:], kin.feature_points[features], atol=1e-12)


def test_scale_offsets_follow_scale_body(male50, on_spheres, compiled):
    """A marker at a sphere centre stays at that sphere's centre on the scaled body."""
    fk, wm = compiled
    markers, spheres, features = on_spheres
    rng = np.random.default_rng(3)
    a = jnp.asarray(rng.uniform(0.8, 1.2, male50.n_segments))
    r = jnp.asarray(rng.uniform(0.8, 1.2, male50.n_segments))
    body = db.scale_body(male50, a, r)
    scaled = scale_offsets(markers, male50, a, r)
    pose = _random_pose(body, rng)
    kin = fk(body, pose)
    p = np.asarray(wm(body, pose, scaled))
    np.testing.assert_allclose(p[: len(spheres)], kin.sphere_centers[spheres], atol=1e-12)
    # A feature point's offset scales radially where the sphere's radius does: still on it.
    np.testing.assert_allclose(p[len(spheres) :], kin.feature_points[features], atol=1e-12)
    with pytest.raises(ValueError, match="per-segment"):
        scale_offsets(markers, male50, a[:3], r[:3])


def test_marker_set_select(male50, gait):
    sub = gait.select(["Top.Head", "R.ASIS"])
    assert sub.names == ("Top.Head", "R.ASIS") and sub.kinds == ("anatomical", "anatomical")
    np.testing.assert_array_equal(sub.offsets[1], gait.offsets[gait.index("R.ASIS")])
    assert sub.segments[0] == male50.segment_index("head")
    with pytest.raises(KeyError, match="Did you mean 'R.ASIS'"):
        gait.index("R.ASlS")
    assert math.isclose(float(sub.weights[0]), 0.1)
