"""Broken body and spine files: every field broken with every value outside its documented
domain (data/SCHEMA.md) is a `BodyFileError` naming the file, the entry and the field; the
values inside the domain, edges included, still load."""

import json

import numpy as np
import pytest
from bodies import mini_doc

import diffbody as db
from diffbody.files._data_files import data_file


class _Missing:
    def __repr__(self):  # a stable test id: pytest-xdist workers must collect the same ids
        return "MISSING"


MISSING = _Missing()  # delete the field


class Raw:
    """JSON text written as is in place of the value: 1e400, or the key given twice."""

    def __init__(self, text: str):
        self.text = text

    def __repr__(self):
        return f"Raw({self.text})"


def twice(value) -> Raw:
    return Raw(f"{json.dumps(value)}, __KEY__: {json.dumps(value)}")


def _apply(doc: dict, path: tuple, value) -> None:
    """Set doc[path] = value; MISSING deletes it."""
    *head, last = path
    obj = doc
    for k in head:
        obj = obj[k]
    if value is MISSING:
        del obj[last]
        return
    if isinstance(value, Raw):  # shared between cases: a copy with this key
        value = Raw(value.text.replace("__KEY__", json.dumps(last)))
    obj[last] = value


def _write(doc: dict, path) -> str:
    raw = {}

    def marker(value: Raw) -> str:
        raw[f'"__RAW_{id(value)}__"'] = value.text
        return f"__RAW_{id(value)}__"

    text = json.dumps(doc, default=marker)
    for key, replacement in raw.items():
        text = text.replace(key, replacement)
    path.write_text(text)
    return str(path)


# --- the domains ------------------------------------------------------------------------------

WRONG_TYPE = ["0.5", True, None, [1], {"a": 1}]
NON_FINITE = [float("nan"), float("inf"), -float("inf"), Raw("1e400"), 10**400]


def strings(example: str) -> list:
    return [MISSING, 1, None, "", ["a"], twice(example)]


def numbers(lo: float, hi: float, example: float) -> list:
    """Outside [lo, hi]: missing, wrong type, non-finite, huge, tiny, negative, given twice."""
    bad = [MISSING, *WRONG_TYPE, *NON_FINITE, 1e200, 1e300, -1e300, twice(example)]
    bad += [x for x in (-1.0, 0.0, 1e-300, hi * 1.01 + 1) if not lo <= x <= hi]
    return bad


def vectors(n: int, bound: float, example: list) -> list:
    """A list of n finite numbers, each within [-bound, bound]."""
    bad = [MISSING, "x", 1, [0] * (n - 1), [0] * (n + 1), [[0]] * n, twice(example)]
    bad += [[0] * (n - 1) + [x] for x in ["0", True, None, *NON_FINITE[:3], Raw("1e400")]]
    bad += [[0] * (n - 1) + [1e200], [0] * (n - 1) + [-bound * 1.01]]
    return bad


def ranges(bound: float, example: list) -> list:
    """[lo, hi] degrees with lo <= hi, within [-bound, bound]."""
    bad = [MISSING, "x", 1, [0], [0, 1, 2], [["0"], 1], ["0", 1], [True, 1], twice(example)]
    return bad + [[float("nan"), 0], [0, float("inf")], [10, -10], [-400, 0], [0, 400], [0, 1e200]]


def objects(example) -> list:
    return [MISSING, "x", 1, [], twice(example)]


LENGTH = numbers(1e-4, 10, 0.5)
MASS = numbers(0, 1000, 30.0)
POSITION = vectors(3, 10, [0, 0, 0.1])
# A direction is normalised on load: only its zero length is out of range, not its size.
DIRECTION = [v for v in vectors(3, np.inf, [0, 0, 1]) if v != [0, 0, 1e200]]
DIRECTION += [[0, 0, 0], [1e-300, 0, 0]]


# --- body files ---------------------------------------------------------------------------------

# (path in the mini document, bad values, the field the message must name)
BODY_FIELDS = [
    (("schema",), strings("diffbody.body/1") + ["diffbody.body/2"], "schema"),
    (("name",), strings("mini"), "name"),
    (("description",), [1, None, "", twice("a body")], "description"),
    (("sources",), [MISSING, "a", [1], None, twice(["a"])], "sources"),
    (("root_joint",), strings("hip") + ["pelvis"], "root_joint"),
    (("segments",), [MISSING, [], {}, "x", None, twice([])], "segments"),
    (("spine",), [1, "", "nothere.json", twice("spine.json")], "spine"),
    (("colour",), ["red"], "colour"),
    (("segments", 0, "name"), strings("trunk") + ["whole_body", "left_thigh"], "name"),
    (("segments", 1, "proximal"), strings("neck") + ["nek", "center_of_gravity"], "proximal"),
    (("segments", 3, "distal"), strings("left_wrist") + ["hip", "neck"], "distal"),
    (("segments", 1, "length"), LENGTH, "length"),
    (("segments", 1, "direction"), DIRECTION, "direction"),
    (("segments", 2, "direction"), [[0, 1, 0], [0, 0, 1]], "direction"),  # a limb hangs
    (("segments", 2, "standard_orientation"), [1, None, "", "left_wing"], "standard_orientation"),
    (("segments", 1, "mass"), MASS, "mass"),
    (("segments", 1, "centroid"), POSITION, "centroid"),
    (("segments", 1, "spheres"), [MISSING, "x", 1, {}, twice([])], "spheres"),
    (("segments", 1, "limits"), objects({"kind": "free"}), "limits"),
    (("segments", 1, "source"), [1, None, ""], "source"),
    (("segments", 1, "wingspan"), [1.0], "wingspan"),
    (("segments", 0, "spheres", 0, "origin"), POSITION, "origin"),
    (("segments", 0, "spheres", 0, "radius"), LENGTH, "radius"),
    (("segments", 0, "spheres", 0, "features"), ["x", 1, {}, [1], [{}]], "features"),
    (("segments", 0, "spheres", 0, "colour"), ["red"], "colour"),
    (("segments", 3, "spheres", 1, "features", 0, "name"), strings("palm") + ["a.b"], "name"),
    (("segments", 3, "spheres", 1, "features", 0, "direction"), DIRECTION, "direction"),
    (("segments", 3, "spheres", 1, "features", 0, "colour"), ["red"], "colour"),
    (("segments", 0, "limits", "kind"), strings("box") + ["ball"], "kind"),
    (("segments", 0, "limits", "swing_x_deg"), ranges(180, [-30, 30]), "swing_x_deg"),
    (("segments", 0, "limits", "swing_y_deg"), ranges(180, [-20, 60]), "swing_y_deg"),
    (("segments", 0, "limits", "twist_deg"), ranges(180, [-40, 40]), "twist_deg"),
    (("segments", 1, "limits", "swing_max_deg"), numbers(1e-3, 179.999, 20.0), "swing_max_deg"),
    (("segments", 2, "limits", "swing_max_deg"), [0, -1, 180, 200, "x"], "swing_max_deg"),
    (("segments", 3, "limits", "swing_x_deg"), [[0, 0]], "swing_x_deg"),  # not for a hinge
    (("segments", 0, "limits", "source"), [1, None], "source"),
]
# Bad values of "features" entries name the entry's fields: the list itself is fine.
FEATURE_ENTRY_FIELDS = {"[1]": None, "[{}]": "direction"}

BODY_CASES = [
    pytest.param(path, value, field, id=f"{'.'.join(map(str, path))}={value!r}"[:90])
    for path, values, field in BODY_FIELDS
    for value in values
]


@pytest.mark.parametrize(("path", "value", "field"), BODY_CASES)
def test_every_broken_body_field_is_named(tmp_path, path, value, field):
    doc = mini_doc()
    _apply(doc, path, value)
    file = _write(doc, tmp_path / "broken.json")
    with pytest.raises(db.BodyFileError) as err:
        db.load_body(file)
    message = str(err.value)
    assert message.startswith(file + ": "), message
    if path[-1] == "features" and repr(value) in FEATURE_ENTRY_FIELDS:
        field = FEATURE_ENTRY_FIELDS[repr(value)]
    if field is not None:
        assert f"field {field!r}" in message, message


# Values at the edges of each domain still load (negative angles, massless, integers, ...).
BODY_VALID = [
    (("segments", 1, "length"), 1e-4),
    (("segments", 1, "length"), 10),
    (("segments", 1, "mass"), 0),
    (("segments", 1, "mass"), 1000.0),
    (("segments", 1, "centroid"), [-10, 10, 0]),
    (("segments", 0, "spheres", 0, "radius"), 1e-4),
    (("segments", 0, "spheres", 0, "origin"), [0, 0, -10.0]),
    (("segments", 1, "direction"), [0, 5, -1]),  # normalised on load
    (("segments", 1, "direction"), [0, 1e300, -1e300]),  # no overflow on normalising
    (("segments", 0, "limits", "twist_deg"), [-180, 180]),
    (("segments", 0, "limits", "swing_y_deg"), [-170.5, -160]),
    (("segments", 0, "limits", "swing_x_deg"), [0, 0]),
    (("segments", 1, "limits", "swing_max_deg"), 179.9),
    (("segments", 1, "spheres"), []),
    (("description",), "a test body"),
]


@pytest.mark.parametrize(("path", "value"), BODY_VALID, ids=lambda v: repr(v)[:40])
def test_valid_edge_values_still_load(tmp_path, path, value):
    doc = mini_doc()
    _apply(doc, path, value)
    body = db.load_body(_write(doc, tmp_path / "edge.json"))
    assert np.all(np.isfinite(np.asarray(body.lengths)))


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b'{"schema": "diffbody.body/1", "name": "caf\xe9"}', "not UTF-8 text (byte 0xe9"),
        (b"\xff\xfe{\x00}\x00", "not UTF-8 text"),
        (b"", "not valid JSON"),
        (b"[" * 100_000, "not valid JSON"),
        (b"[]", "must be a JSON object"),
    ],
    ids=["latin-1", "utf-16", "empty", "deeply nested", "a list"],
)
def test_unreadable_body_file_is_named(tmp_path, content, fragment):
    path = tmp_path / "body.json"
    path.write_bytes(content)
    with pytest.raises(db.BodyFileError) as err:
        db.load_body(path)
    assert str(err.value).startswith(str(path) + ": ") and fragment in str(err.value)


def test_a_directory_is_not_a_body_file(tmp_path):
    with pytest.raises(db.BodyFileError, match="is a directory; expected a body JSON file"):
        db.load_body(tmp_path)
    with pytest.raises(db.BodyFileError, match="is a directory; expected a spine JSON file"):
        db.load_spine(tmp_path)


def test_huge_dimensions_were_silent_before(tmp_path):
    """Regression: 1e300 lengths loaded and gave non-finite float32 kinematics; 1e-300
    became 0."""
    for value, fragment in [(1e300, "got 1e+300"), (1e-300, "got 1e-300")]:
        doc = mini_doc()
        doc["segments"][1]["length"] = value
        with pytest.raises(db.BodyFileError) as err:
            db.load_body(_write(doc, tmp_path / "huge.json"))
        message = str(err.value)
        assert "'length': must lie in [0.0001, 10] m, " + fragment in message, message


# --- spine files --------------------------------------------------------------------------------


def spine_doc() -> dict:
    return json.loads(data_file("spine.json").read_text())


T3 = ("joints", 3)  # T3_T4
SPINE_FIELDS = [
    (("schema",), strings("diffbody.spine/1") + ["diffbody.spine/0"], "schema"),
    (("sources",), ["a", [1], None, twice(["a"])], "sources"),
    (("angles",), [1, None, ""], "angles"),
    (("initiator",), [1, None, "", "T13_L1", twice("T12_L1")], "initiator"),
    (("joints",), [MISSING, [], {}, "x", None, twice([])], "joints"),
    (("vertebrae",), [MISSING, {}, "x", None, [], twice([])], "vertebrae"),
    (("extra",), [1], "extra"),
    (T3 + ("name",), strings("T3_T4") + ["T6_T7"], "name"),
    (T3 + ("segment",), strings("T3") + ["T6", "whole_body"], "segment"),
    (T3 + ("rest_deg",), vectors(3, 90, [4.07, 0, 0]) + [[0, 0, 0]], "rest_deg"),
    (T3 + ("limits_deg",), objects({"flexion": [0, 1]}), "limits_deg"),
    (T3 + ("limits_deg", "axial"), ranges(90, [-8, 8]) + [[-8, 8, 1]], "axial"),
    (T3 + ("limits_deg", "twist"), [[-1, 1]], "twist"),
    (T3 + ("disc_height_mm",), numbers(0, 50, 2.85), "disc_height_mm"),
    (T3 + ("flexion_axis_offset_mm",), vectors(2, 100, [-5, -1.4]), "flexion_axis_offset_mm"),
    (T3 + ("source",), [1, None, ""], "source"),
    (T3 + ("colour",), ["red"], "colour"),
    (("vertebrae", 3, "name"), strings("T4") + ["T5"], "name"),
    (("vertebrae", 3, "size_mm"), vectors(3, 200, [20, 27, 17]) + [[20, 0, 17]], "size_mm"),
    (("vertebrae", 3, "colour"), ["red"], "colour"),
]
SPINE_CASES = [
    pytest.param(path, value, field, id=f"{'.'.join(map(str, path))}={value!r}"[:90])
    for path, values, field in SPINE_FIELDS
    for value in values
]


@pytest.mark.parametrize(("path", "value", "field"), SPINE_CASES)
def test_every_broken_spine_field_is_named(tmp_path, path, value, field):
    doc = spine_doc()
    _apply(doc, path, value)
    file = _write(doc, tmp_path / "spine.json")
    with pytest.raises(db.BodyFileError) as err:
        db.load_spine(file)
    message = str(err.value)
    assert message.startswith(file + ": ") and repr(field) in message, message


def _drop(doc, section, name):
    doc[section] = [e for e in doc[section] if e["name"] != name]


@pytest.mark.parametrize(
    ("mutate", "entry", "fragment"),
    [
        (lambda d: _drop(d, "vertebrae", "T7"), "vertebra 'T8' (vertebrae[6])", "expected 'T7'"),
        (lambda d: d["vertebrae"].pop(), "field 'vertebrae'", "missing ['L5']"),
        (lambda d: d["vertebrae"].append(d["vertebrae"][0]), "vertebrae[17]", "17 expected"),
        (lambda d: d["joints"].append(d["joints"][5]), "joints[18]", "duplicate name"),
        (lambda d: _drop(d, "joints", "T12_L1"), "field 'initiator'", "no joint 'T12_L1'"),
        (lambda d: d["joints"][4]["rest_deg"].__setitem__(1, "0"), "'T4_T5'", "must be a number"),
        (lambda d: d["joints"][4]["limits_deg"]["axial"].__setitem__(1, 400), "axial", "[-90, 90]"),
    ],
    ids=[
        "missing vertebra",
        "missing last vertebra",
        "extra vertebra",
        "duplicate joint",
        "no initiator",
        "string number",
        "axial 400",
    ],
)
def test_spine_structure_errors(tmp_path, mutate, entry, fragment):
    """Regression: each of these loaded silently or failed without naming the joint."""
    doc = spine_doc()
    mutate(doc)
    file = _write(doc, tmp_path / "spine.json")
    with pytest.raises(db.BodyFileError) as err:
        db.load_spine(file)
    assert file in str(err.value) and entry in str(err.value) and fragment in str(err.value)


def test_a_spine_without_t12_l1_names_its_initiator(tmp_path):
    doc = spine_doc()
    doc["initiator"] = "T11_T12"
    doc["joints"][12]["name"] = "TL"
    spine = db.load_spine(_write(doc, tmp_path / "spine.json"))
    assert spine.joint_names[spine.initiator] == "T11_T12"
    assert db.load_spine().joint_names[db.load_spine().initiator] == "T12_L1"


def test_spine_edge_values_still_load(tmp_path):
    doc = spine_doc()
    doc["joints"][3]["disc_height_mm"] = 0  # a fused level
    doc["joints"][3]["limits_deg"]["axial"] = [-90, 90]
    doc["joints"][3]["rest_deg"] = [2.07, -90, 0]  # at its limits
    spine = db.load_spine(_write(doc, tmp_path / "spine.json"))
    assert spine.rest.shape == (18, 3) and float(spine.disc_heights[3]) == 0.0


def test_a_body_names_its_missing_spine_file(tmp_path):
    doc = mini_doc()
    doc["spine"] = "nowhere/spine.json"
    file = _write(doc, tmp_path / "body.json")
    with pytest.raises(db.BodyFileError, match=r"field 'spine': no spine file at .*nowhere"):
        db.load_body(file)
