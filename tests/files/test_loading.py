"""Loading body files: the default bodies, validation with clear messages."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from bodies import mini_doc, write

import diffbody as db


def test_mini_body_loads(tmp_path):
    body = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    assert body.segment_names[0] == "whole_body" and body.joint_names[0] == "center_of_gravity"
    assert body.joint_names[1] == "hip"
    assert set(body.limit_kind) == {"free", "box", "cone", "hinge"}
    assert body.feature_names == ("left_upper_arm.elbow", "left_forearm.palm")
    # Breadth-first: every parent comes before its children.
    for i, p in enumerate(body.parent):
        assert p < i
    assert body.children("trunk") == ("left_clavicle",)


@pytest.mark.parametrize("variant", ["male50", "female50"])
def test_default_bodies_load(variant):
    body = db.load_body(variant=variant)
    assert body.n_spheres >= 200
    for name in [
        "left_hand.palm",
        "left_hand.fingertip",
        "right_hand.palm",
        "left_foot.sole",
        "left_foot.toe",
        "right_foot.toe",
        "head.top",
        "head.nose",
        "head.left_eye",
        "head.right_eye",
        "left_forearm.elbow",
        "right_thigh.knee",
        "left_upper_arm.shoulder",
        "right_thigh.hip",
    ]:
        body.feature_index(name)
    vertebrae = [f"T{i}" for i in range(1, 13)] + [f"L{i}" for i in range(1, 6)]
    for v in vertebrae:
        body.segment_index(v)


def test_unknown_names_list_valid_ones(male50):
    with pytest.raises(KeyError, match="left_forearm"):
        male50.segment_index("left_fore_arm")
    with pytest.raises(KeyError, match="Valid features"):
        male50.feature_index("left_hand.thumb")


def test_unknown_variant_lists_available():
    with pytest.raises(ValueError, match="female50"):
        db.load_body(variant="male99")


def test_local_directions_follow_the_seed(male50):
    # Seed 000: "the negative Z-axis is 'up' for the lower arm and the positive X-axis is
    # 'front' for the head".
    dirs = np.asarray(male50.local_directions)
    np.testing.assert_allclose(
        dirs[male50.segment_index("left_forearm")][2], [0, 0, -1], atol=1e-12
    )
    np.testing.assert_allclose(dirs[male50.segment_index("head")][0], [1, 0, 0], atol=1e-12)


def test_enclosure_holds_every_sphere_in_any_twist(male50):
    """The enclosure is centred on the segment axis, so twisting spheres about it keeps them
    inside; and it is the smallest such sphere (a grid search finds nothing smaller)."""
    o = np.asarray(male50.sphere_origins)
    r = np.asarray(male50.sphere_radii)
    seg = np.asarray(male50.sphere_segment)
    for i in range(1, male50.n_segments):
        k = seg == i
        if not k.any():
            continue
        zc, R = float(male50.enclosure_z[i]), float(male50.enclosure_radii[i])
        dist = np.sqrt(np.sum(o[k, :2] ** 2, 1) + (o[k, 2] - zc) ** 2) + r[k]
        assert np.all(dist <= R + 1e-12)
        grid = np.linspace(o[k, 2].min() - 0.1, o[k, 2].max() + 0.1, 2001)
        best = min(
            np.max(np.sqrt(np.sum(o[k, :2] ** 2, 1) + (o[k, 2] - z) ** 2) + r[k]) for z in grid
        )
        assert R <= best + 1e-12


def test_masses_sum_to_the_body_mass(male50, female50):
    # ANSUR II median body masses (data/ansur2_percentiles.csv).
    assert math.isclose(float(jnp.sum(male50.masses)), 84.6, rel_tol=1e-3)
    assert math.isclose(float(jnp.sum(female50.masses)), 66.8, rel_tol=1e-3)


# --- malformed files ------------------------------------------------------------------------


def seg(doc, name):
    return next(s for s in doc["segments"] if s["name"] == name)


def _set(path, value):
    def mutate(doc):
        *head, last = path
        obj = doc
        for k in head:
            obj = (
                seg(obj, k)
                if isinstance(k, str)
                and isinstance(obj, dict)
                and "segments" in obj
                and k not in obj
                else obj[k]
            )
        obj[last] = value

    return mutate


def _del(path):
    def mutate(doc):
        *head, last = path
        obj = doc
        for k in head:
            obj = (
                seg(obj, k) if isinstance(k, str) and "segments" in obj and k not in obj else obj[k]
            )
        del obj[last]

    return mutate


def _cycle(doc):
    # trunk starts at hip; make a loop clavicle -> upper arm -> clavicle away from the root.
    seg(doc, "left_clavicle")["proximal"] = "left_elbow"


def _dup_name(doc):
    seg(doc, "left_thigh")["name"] = "trunk"


def _dup_distal(doc):
    seg(doc, "left_thigh")["distal"] = "neck"


def _dup_feature(doc):
    seg(doc, "left_upper_arm")["spheres"][0]["features"] = [
        {"name": "elbow", "direction": [1, 0, 0]}
    ]


BAD = [  # (id, mutation, entry fragment, field, message fragment)
    ("wrong schema", _set(["schema"], "body/0"), "top level", "schema", "diffbody.body/1"),
    ("missing segments", _del(["segments"]), "top level", "segments", "missing"),
    ("unknown top field", _set(["colour"], "red"), "top level", "colour", "unknown field"),
    ("empty segments", _set(["segments"], []), "top level", "segments", "non-empty"),
    ("missing length", _del(["trunk", "length"]), "'trunk'", "length", "missing"),
    (
        "length wrong type",
        _set(["trunk", "length"], "0.5"),
        "'trunk'",
        "length",
        "must be a number",
    ),
    (
        "negative length",
        _set(["left_forearm", "length"], -0.26),
        "'left_forearm'",
        "length",
        "[0.0001, 10] m",
    ),
    ("nan length", _set(["trunk", "length"], float("nan")), "'trunk'", "length", "finite"),
    (
        "negative radius",
        _set(["trunk", "spheres", 0, "radius"], -0.1),
        "spheres[0]",
        "radius",
        "[0.0001, 10] m",
    ),
    (
        "unknown parent",
        _set(["left_clavicle", "proximal"], "nek"),
        "'left_clavicle'",
        "proximal",
        "unknown joint 'nek'",
    ),
    ("cycle", _cycle, "segment", "proximal", "cycle"),
    ("duplicate segment", _dup_name, "segments[4]", "name", "duplicate segment name"),
    ("duplicate joint", _dup_distal, "'left_thigh'", "distal", "already the distal joint"),
    (
        "inverted limits",
        _set(["trunk", "limits", "swing_y_deg"], [60, -20]),
        "(segments[0]), limits",
        "swing_y_deg",
        "inverted",
    ),
    ("zero direction", _set(["trunk", "direction"], [0, 0, 0]), "'trunk'", "direction", "non-zero"),
    ("short direction", _set(["trunk", "direction"], [0, 1]), "'trunk'", "direction", "3 numbers"),
    (
        "unknown standard",
        _set(["left_upper_arm", "standard_orientation"], "left_wing"),
        "'left_upper_arm'",
        "standard_orientation",
        "left_arm",
    ),
    (
        "limb not hanging",
        _set(["left_upper_arm", "direction"], [0, 1, 0]),
        "'left_upper_arm'",
        "direction",
        "hang straight down",
    ),
    ("unknown limit kind", _set(["trunk", "limits", "kind"], "ball"), "limits", "kind", "box"),
    ("negative mass", _set(["trunk", "mass"], -1.0), "'trunk'", "mass", "[0, 1000] kg"),
    ("duplicate feature", _dup_feature, "features[0]", "name", "unique"),
    (
        "zero feature direction",
        _set(["left_forearm", "spheres", 1, "features", 0, "direction"], [0, 0, 0]),
        "features[0]",
        "direction",
        "non-zero",
    ),
    ("unused root", _set(["root_joint"], "pelvis"), "top level", "root_joint", "no segment starts"),
    (
        "cone too wide",
        _set(["left_clavicle", "limits", "swing_max_deg"], 180),
        "limits",
        "swing_max_deg",
        "< 180",
    ),
    (
        "misspelt field",
        _set(["trunk", "spheres", 0, "radus"], 0.1),
        "spheres[0]",
        "radus",
        "allowed fields",
    ),
    (
        "infinite centroid",
        _set(["trunk", "centroid"], [0, float("inf"), 0]),
        "'trunk'",
        "centroid",
        "finite",
    ),
    (
        "missing twist",
        _del(["left_forearm", "limits", "twist_deg"]),
        "limits",
        "twist_deg",
        "missing",
    ),
    ("reserved name", _set(["trunk", "name"], "whole_body"), "segments[0]", "name", "reserved"),
    (
        "root as distal",
        _set(["left_forearm", "distal"], "hip"),
        "'left_forearm'",
        "distal",
        "root joint",
    ),
    (
        "limit out of range",
        _set(["trunk", "limits", "twist_deg"], [-200, 40]),
        "limits",
        "twist_deg",
        "[-180, 180]",
    ),
]


@pytest.mark.parametrize("case", BAD, ids=[b[0] for b in BAD])
def test_malformed_file_names_file_entry_field(tmp_path, case):
    _, mutate, entry, field, fragment = case
    doc = mini_doc()
    mutate(doc)
    path = write(doc, tmp_path / "bad.json")
    with pytest.raises(db.BodyFileError) as err:
        db.load_body(path)
    msg = str(err.value)
    assert path in msg and entry in msg and repr(field) in msg and fragment in msg, msg


def test_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.json"):
        db.load_body(tmp_path / "nothere.json")


def test_invalid_json_gives_line_and_column(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{"schema": "diffbody.body/1",\n "name": }')
    with pytest.raises(db.BodyFileError, match=r"broken.json: not valid JSON: .* line 2 column 10"):
        db.load_body(path)


def test_nan_literal_in_json_is_rejected(tmp_path):
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(mini_doc()).replace('"mass": 30.0', '"mass": NaN'))
    with pytest.raises(db.BodyFileError, match="'mass': must be a finite number"):
        db.load_body(path)
