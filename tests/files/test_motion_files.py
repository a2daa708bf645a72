"""OpenSim motion files (diffbody.files._motion_files): round trips, OpenSim's own file, bad
files' messages, the atomic write, and OpenSim 4 reading what `write_mot` writes."""

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffbody.files._data_files import data_file
from diffbody.files._motion_files import MotionFileError, read_mot, write_mot

OPENSIM_MOT = "mocap/subject01_walk1_ik_opensim.mot"
HEADER = "name\nversion=1\nnRows=2\nnColumns=3\ninDegrees=yes\nendheader\n"

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=20)
@given(
    n=st.integers(0, 5),
    labels=st.lists(
        st.text(st.characters(codec="utf-8"), min_size=1).filter(
            lambda s: (
                s == s.strip()
                and s.lower() != "time"
                and not any(c.isspace() and c != " " for c in s)
            )
        ),
        max_size=4,
        unique=True,
    ),
    data=st.data(),
)
def test_round_trip_gives_back_every_float(tmp_path_factory, n, labels, data):
    times = np.cumsum(data.draw(st.lists(st.floats(1e-6, 10.0), min_size=n, max_size=n)))
    columns = {
        label: np.array(data.draw(st.lists(finite | st.just(math.nan), min_size=n, max_size=n)))
        for label in labels
    }
    path = tmp_path_factory.mktemp("mot") / "walk.mot"
    assert write_mot(path, times, columns) == path
    t, back = read_mot(path)
    assert np.array_equal(t, times) and list(back) == labels
    for label in labels:
        assert np.array_equal(back[label], columns[label], equal_nan=True)
        assert back[label].shape == (n,)


def test_reads_opensims_own_file():
    times, columns = read_mot(data_file(OPENSIM_MOT))
    assert times.shape == (73,) and times[0] == 0.4 and times[-1] == pytest.approx(1.6)
    assert len(columns) == 23 and list(columns)[:2] == ["pelvis_tilt", "pelvis_list"]
    assert columns["knee_angle_r"][0] == -54.91982332
    last = data_file(OPENSIM_MOT).read_text().split()[-1]
    assert columns["lumbar_rotation"][-1] == float(last)


def test_header_says_what_opensim_needs(tmp_path):
    path = write_mot(tmp_path / "a.mot", [0.0, 0.5], {"knee_angle_r": [1.0, 2.5]}, name="IK")
    lines = path.read_text().splitlines()
    assert lines[:7] == [
        "IK",
        "version=1",
        "nRows=2",
        "nColumns=2",
        "inDegrees=yes",
        "endheader",
        "time\tknee_angle_r",
    ]
    assert lines[7:] == ["0.0\t1.0", "0.5\t2.5"]
    write_mot(path, [0.0], {"x": [1.0]}, in_degrees=False)
    assert "inDegrees=no" in path.read_text().splitlines()


BAD_FILES = [
    ("name\nversion=1\n", r"line 3: no 'endheader' line"),
    ("name\nnRows=two\nendheader\ntime\ta\n", r"line 2: nRows='two': expected a whole number"),
    ("name\nendheader\n", r"line 3: expected the column labels after 'endheader'"),
    ("name\nendheader\nframe\ta\n1\t2\n", r"line 3: the first column must be 'time'"),
    ("name\nendheader\ntime\ta\ta\n", r"line 3: column labels \['a'\] appear more than once"),
    (HEADER + "time\ta\n", r"line 7: 2 column labels, but nColumns \(line 4\) says 3"),
    (HEADER + "time\ta\tb\n0\t1\t2\n1\t2\n", r"line 9: 2 values for 3 columns"),
    (HEADER + "time\ta\tb\n0\t1\t2\n1\tx\t2\n", r"line 9: column 2 \(a\): expected a number"),
    (HEADER + "time\ta\tb\n0\t1\t2\n", r"line 3: nRows=2 but the file has 1 data rows"),
    (HEADER + "time\ta\tb\n0\t1\t2\n\nnan\t1\t2\n", r"line 10: the time is not a finite"),
]


@pytest.mark.parametrize("text, message", BAD_FILES)
def test_bad_files_name_the_file_the_line_and_the_fix(tmp_path, text, message):
    path = tmp_path / "bad.mot"
    path.write_text(text)
    with pytest.raises(MotionFileError, match=re.escape(str(path)) + ": " + message):
        read_mot(path)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such motion file"):
        read_mot(tmp_path / "none.mot")
    (tmp_path / "b.mot").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(MotionFileError, match="not UTF-8 text"):
        read_mot(tmp_path / "b.mot")


@pytest.mark.parametrize(
    "times, columns, kwargs, message",
    [
        ([0.0, 0.0], {"a": [1, 2]}, {}, "strictly increasing"),
        ([[0.0]], {"a": [1]}, {}, "one-dimensional"),
        ([0.0, 1.0], {"a": [1]}, {}, "one value per time"),
        ([0.0], {"a\tb": [1]}, {}, "cannot be written"),
        ([0.0], {"a\x0cb": [1]}, {}, "cannot be written"),
        ([0.0], {"time": [1]}, {}, "cannot be written"),
        ([0.0], {"a": [math.inf]}, {}, "infinite"),
        ([0.0], {"a": [1]}, {"name": "a=b"}, "first line"),
    ],
)
def test_bad_input_to_write(tmp_path, times, columns, kwargs, message):
    path = tmp_path / "old.mot"
    write_mot(path, [0.0], {"kept": [1.0]})
    with pytest.raises(ValueError, match=message):
        write_mot(path, times, columns, **kwargs)
    assert list(read_mot(path)[1]) == ["kept"]  # the old file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["old.mot"]  # no temporary file left


def test_opensim_reads_what_write_mot_writes(tmp_path):
    """OpenSim 4's own reader (TimeSeriesTable, its STOFileAdapter) takes a written file:
    the same columns in the same order, the same times and values."""
    opensim = pytest.importorskip("opensim")
    times, columns = read_mot(data_file(OPENSIM_MOT))
    columns = {"joint_" + name: values / 3.0 for name, values in columns.items()}
    path = write_mot(tmp_path / "angles.mot", times, columns, name="angles")
    table = opensim.TimeSeriesTable(str(path))
    assert list(table.getColumnLabels()) == list(columns)
    assert np.array_equal(np.asarray(table.getIndependentColumn()), times)
    for name, values in columns.items():
        assert np.array_equal(table.getDependentColumn(name).to_numpy(), values), name
    assert table.getTableMetaDataAsString("inDegrees") == "yes"
