"""OpenSim's set-up files (diffbody.files._opensim_files): the IK task set of the shipped
set-up and of written files, the marker set of a marker-set file and of a model and where its
markers land on the default body against opensim-gait.json (the shipped walk fitted with it
against opensim-gait.json: benchmarks/mocap.py)."""

import re

import numpy as np
import pytest

from diffbody.files._data_files import data_file
from diffbody.files._marker_trial import MarkerFileError
from diffbody.files._markerset_file import load_markerset
from diffbody.files._opensim_files import (
    OPENSIM_BODIES,
    load_opensim_markerset,
    read_ik_tasks,
)
from diffbody.mocap._markerset import world_markers

SETUP_IK = data_file("mocap/subject01_Setup_IK.xml")
MARKERSET_XML = data_file("mocap/gait2354_Scale_MarkerSet.xml")
GENERIC_OSIM = data_file("mocap/gait2354_simbody.osim")


def task_set(objects: str) -> str:
    return (
        '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="40000">\n'
        f'<IKTaskSet name="tasks">\n<objects>\n{objects}\n</objects>\n</IKTaskSet>\n'
        "</OpenSimDocument>\n"
    )


def marker_task(name: str, apply="true", weight="1") -> str:
    return (
        f'<IKMarkerTask name="{name}"><apply>{apply}</apply><weight>{weight}</weight>'
        "</IKMarkerTask>"
    )


# --- IK tasks ------------------------------------------------------------------------------
def test_the_shipped_setup_gives_opensims_31_marker_tasks():
    """Every IKMarkerTask of subject01_Setup_IK.xml, read here by a regular expression:
    31 markers, all applied, with their weights (10 for the ASIS, sacrum, heels and toe
    tips); its four IKCoordinateTasks are not markers."""
    text = SETUP_IK.read_text()
    found = re.findall(
        r'<IKMarkerTask name="([^"]+)">.*?<apply>\s*(\w+)\s*</apply>.*?'
        r"<weight>\s*([^<]+?)\s*</weight>",
        text,
        flags=re.DOTALL,
    )
    expected = {name: float(w) for name, apply, w in found if apply == "true"}
    tasks = read_ik_tasks(SETUP_IK)
    assert len(found) == 31 and tasks == expected
    assert list(tasks) == [name for name, _, _ in found]
    assert {n for n, w in tasks.items() if w == 10} == {
        "R.ASIS",
        "L.ASIS",
        "V.Sacral",
        "R.Heel",
        "L.Heel",
        "R.Toe.Tip",
        "L.Toe.Tip",
    }
    assert (tasks["R.Acromium"], tasks["Top.Head"], tasks["Sternum"]) == (0.5, 0.1, 1.0)
    assert not any("angle" in n for n in tasks)


def test_a_task_set_file(tmp_path):
    """A task-set file: apply in any case, false left out, OpenSim's defaults (applied,
    weight 1) where a field is absent, a weight 0 kept, coordinate tasks ignored; a set-up
    that names its task set's file reads that file."""
    objects = "\n".join(
        [
            marker_task("A", "TRUE", "2.5"),
            marker_task("B", "false", "3"),
            marker_task("C", " True ", "0"),
            '<IKMarkerTask name="D"></IKMarkerTask>',
            '<IKCoordinateTask name="knee_angle_r"><apply>true</apply>'
            "<weight>1000</weight></IKCoordinateTask>",
        ]
    )
    tasks = tmp_path / "tasks.xml"
    tasks.write_text(task_set(objects))
    assert read_ik_tasks(tasks) == {"A": 2.5, "C": 0.0, "D": 1.0}
    setup = tmp_path / "setup.xml"
    setup.write_text(
        '<?xml version="1.0"?><OpenSimDocument><InverseKinematicsTool name="s">'
        '<IKTaskSet file="tasks.xml"/></InverseKinematicsTool></OpenSimDocument>'
    )
    assert read_ik_tasks(setup) == {"A": 2.5, "C": 0.0, "D": 1.0}


@pytest.mark.parametrize(
    "content, message",
    [
        (None, r"missing\.xml: no such OpenSim IK set-up or task set file"),
        ("<OpenSimDocument>\n<IKTaskSet>\n</OpenSimDocument>\n", r"bad\.xml: line 3, column"),
        ("<OpenSimDocument><Model/></OpenSimDocument>", r"no <IKTaskSet> in the document"),
        (task_set("<IKMarkerTask><weight>1</weight></IKMarkerTask>"), r"task 0 .*'name': missing"),
        (task_set(marker_task("R.ASIS", weight="-1")), r"'R\.ASIS', field 'weight'.*got '-1'"),
        (task_set(marker_task("R.ASIS", weight="nan")), r"'R\.ASIS', field 'weight'.*'nan'"),
        (task_set(marker_task("R.ASIS", weight="ten")), r"'R\.ASIS', field 'weight'.*'ten'"),
        (task_set(marker_task("A") + marker_task("A")), r"'A', field 'name': given twice"),
    ],
)
def test_bad_task_sets(tmp_path, content, message):
    path = tmp_path / ("missing.xml" if content is None else "bad.xml")
    if content is not None:
        path.write_text(content)
    # A missing file is a FileNotFoundError, as for every reader (files/_data_files.read_text).
    error = FileNotFoundError if content is None else MarkerFileError
    with pytest.raises(error, match=message):
        read_ik_tasks(path)


# --- marker sets ---------------------------------------------------------------------------
def as_osim(markerset_xml: str, model_text: str) -> str:
    """The generic model (no markers) with the markers of an OpenSim 3 marker-set file
    written in OpenSim 4's style (`<socket_parent_frame>/bodyset/...`)."""
    markers = re.findall(
        r'<Marker name="([^"]+)">.*?<body>\s*(\S+)\s*</body>.*?<location>([^<]+)</location>'
        r".*?<fixed>\s*(\w+)\s*</fixed>",
        markerset_xml,
        flags=re.DOTALL,
    )
    objects = "".join(
        f'<Marker name="{n}"><socket_parent_frame>/bodyset/{b}</socket_parent_frame>'
        f"<location>{' '.join(loc.split())}</location><fixed>{f}</fixed></Marker>"
        for n, b, loc, f in markers
    )
    text, count = re.subn(
        r'(<MarkerSet name="markerset">\s*)<objects />',
        rf"\1<objects>{objects}</objects>",
        model_text,
    )
    assert count == 1 and len(markers) == 39
    return text


def test_the_xml_and_the_osim_give_the_same_markers(male50, tmp_path):
    """gait2354's marker-set file (OpenSim 3's `<body>`) and the generic model carrying the
    same markers (OpenSim 4's `<socket_parent_frame>`): the same 39 markers, segments and
    offsets, all "tracking" (none is fixed) with weight 1. The shipped subject01 model's
    markers (placed by OpenSim's scale tool) go to the same segments."""
    from_xml = load_opensim_markerset(MARKERSET_XML, male50)
    model = tmp_path / "gait2354_with_markers.osim"
    model.write_text(as_osim(MARKERSET_XML.read_text(), GENERIC_OSIM.read_text()))
    from_osim = load_opensim_markerset(model, male50)
    assert from_xml.n_markers == 39 and from_osim.names == from_xml.names
    assert from_osim.segments == from_xml.segments
    np.testing.assert_allclose(from_osim.offsets, from_xml.offsets, atol=1e-12)
    assert set(from_xml.kinds) == {"tracking"} and np.all(from_xml.weights == 1)
    np.testing.assert_allclose(from_xml.tolerances, 0.02)
    scaled = load_opensim_markerset(data_file("mocap/subject01_simbody.osim"), male50)
    assert scaled.names == from_xml.names and scaled.segments == from_xml.segments


def test_markers_land_near_opensim_gait(male50):
    """Each marker in the standard position against opensim-gait.json's marker of the same
    name on the same segment: the pelvis, leg and foot markers within 5 cm (4.7 cm at most,
    the shank clusters: OpenSim's generic places are not this body's), the top of the head
    within 5 cm (4.0). The sternum (15.3 cm) and the acromia (11.2 cm) are OpenSim's
    generic torso's: its sternum lies 7 cm in front of the lumbosacral joint, on a chest
    far shallower than this body's (ANSUR II's median, 253 mm deep), and its acromia 15 cm
    lateral of the midline against the default body's 19-20 cm; registration moves them."""
    osim = load_opensim_markerset(MARKERSET_XML, male50)
    gait = load_markerset("opensim-gait", male50).select(osim.names)
    assert osim.segments == gait.segments
    rest = male50.rest_pose()
    apart = np.linalg.norm(
        world_markers(male50, rest, osim) - world_markers(male50, rest, gait), axis=1
    )
    bounds = {"Sternum": 0.16, "R.Acromium": 0.12, "L.Acromium": 0.12}
    for name, d in zip(osim.names, apart):
        assert d < bounds.get(name, 0.05), (name, d)


def test_fixed_markers_are_anatomical(male50, tmp_path):
    text = MARKERSET_XML.read_text().replace("<fixed> false </fixed>", "<fixed> TRUE </fixed>", 1)
    path = tmp_path / "fixed.xml"
    path.write_text(text)
    ms = load_opensim_markerset(path, male50)
    assert ms.kinds[0] == "anatomical" and ms.kinds[1] == "tracking"
    np.testing.assert_allclose(ms.tolerances[:2], [0.005, 0.02])


def test_the_table_knows_opensims_gait_bodies():
    gait = ["pelvis", "torso"] + [
        f"{b}_{s}"
        for b in ("femur", "tibia", "patella", "talus", "calcn", "toes")
        + ("humerus", "ulna", "radius", "hand")
        for s in "rl"
    ]
    assert sorted(OPENSIM_BODIES) == sorted(gait)


def marker_set(markers: str) -> str:
    return (
        '<?xml version="1.0"?>\n<OpenSimDocument Version="40000">\n<MarkerSet name="lab">'
        f"<objects>\n{markers}\n</objects></MarkerSet>\n</OpenSimDocument>\n"
    )


@pytest.mark.parametrize(
    "content, message",
    [
        (
            marker_set(
                '<Marker name="SCAP"><body>scapula_r</body><location>0 0 0</location></Marker>'
            ),
            r"marker 'SCAP', field 'body': OpenSim body 'scapula_r' has no diffbody segment; "
            r"the bodies known are pelvis, femur_r",
        ),
        (
            marker_set(
                '<Marker name="K"><socket_parent_frame>/bodyset/femur_r/knee_offset'
                "</socket_parent_frame><location>0 0 0</location></Marker>"
            ),
            r"marker 'K', field 'body': OpenSim body 'knee_offset'",
        ),
        (
            marker_set(
                '<Marker name="K"><body>femur_r</body><location>0 nan 0</location></Marker>'
            ),
            r"marker 'K', field 'location': must be three finite numbers .*'0 nan 0'",
        ),
        (
            marker_set('<Marker name="K"><body>femur_r</body><location>0 0</location></Marker>'),
            r"marker 'K', field 'location'",
        ),
        (marker_set("<Marker><body>femur_r</body></Marker>"), r"marker 0 .*'name': missing"),
        ("<OpenSimDocument><Model/></OpenSimDocument>", r"no <MarkerSet> in the document"),
        ("<OpenSimDocument>\n<MarkerSet>\n", r"line 3, column"),
    ],
)
def test_bad_marker_sets(male50, tmp_path, content, message):
    path = tmp_path / "lab.xml"
    path.write_text(content)
    with pytest.raises(MarkerFileError, match=message):
        load_opensim_markerset(path, male50)


def test_a_model_without_markers(male50):
    """The generic gait2354 model ships with an empty MarkerSet: the error says to use its
    marker-set file."""
    with pytest.raises(MarkerFileError, match=r"gait2354_simbody\.osim: .*holds no <Marker>"):
        load_opensim_markerset(GENERIC_OSIM, male50)


def test_a_body_without_the_segment(male50, tmp_path):
    """A body that lacks a segment the table names: the marker cannot be placed."""
    import dataclasses

    names = tuple("clavicle_r" if n == "right_clavicle" else n for n in male50.segment_names)
    body = dataclasses.replace(male50, segment_names=names)
    path = tmp_path / "acromion.xml"
    path.write_text(
        marker_set('<Marker name="RA"><body>torso</body><location>0 0.4 0.15</location></Marker>')
    )
    with pytest.raises(MarkerFileError, match=r"'RA', field 'body': .*no segment 'right_clavicle'"):
        load_opensim_markerset(path, body)
