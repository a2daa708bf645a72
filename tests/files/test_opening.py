"""Every reader opens its file one way (`files/_data_files.read_text`): a missing file is a
FileNotFoundError naming it, a folder and bytes that are not UTF-8 are the reader's own error
naming the file (and the line or row of the bad byte)."""

import pytest

import diffbody as db
from diffbody.files._skeleton_file import read_skeleton
from diffbody.files._webb_files import read_anchor, read_depths, read_points

NAMES = ("center_hip", "left_hip")
READERS = {
    "body": (lambda p: db.load_body(p), db.BodyFileError, "line"),
    "motion": (db.read_mot, db.MotionFileError, "line"),
    "trc": (db.read_trc, db.MarkerFileError, "line"),
    "opensim": (db.read_ik_tasks, db.MarkerFileError, "line"),
    "markerset": (lambda p: db.load_markerset(p, db.load_body()), db.MarkerFileError, "line"),
    "skeleton": (read_skeleton, ValueError, "line"),
    "points": (lambda p: read_points(p, NAMES), ValueError, "row"),
    "depths": (lambda p: read_depths(p, 2), ValueError, "row"),
    "anchor": (lambda p: read_anchor(p, ("a->b",)), ValueError, "line"),
}
SUFFIX = {"body": ".json", "markerset": ".json", "opensim": ".xml", "trc": ".trc"}


@pytest.mark.parametrize("kind", READERS)
def test_a_missing_file_a_folder_and_bad_bytes_are_named(kind, tmp_path):
    read, error, unit = READERS[kind]
    path = tmp_path / f"in{SUFFIX.get(kind, '.txt')}"
    with pytest.raises(FileNotFoundError, match=f"{path}: no such .*file"):
        read(path)
    folder = tmp_path / f"folder{SUFFIX.get(kind, '')}"
    folder.mkdir()
    with pytest.raises(error, match=f"{folder}: is a directory; expected an? .*file"):
        read(folder)
    path.write_bytes(b"first line\nsecond \xff line\n")
    with pytest.raises(error, match=rf"{path}: {unit} 2: not UTF-8 text \(byte 0xff"):
        read(path)


def test_a_byte_order_mark_is_dropped(tmp_path):
    path = tmp_path / "skeleton.json"
    path.write_bytes(b'\xef\xbb\xbf{"joints": [{"name": "a", "parent": null}]}')
    assert read_skeleton(path) == [("a", None)]
