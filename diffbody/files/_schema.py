"""The body and spine file schemas (data/SCHEMA.md): schema names, the fields each object
takes, and the physical ranges values must lie in. `_body_file` and `_spine_file` read files
against them; `_saving` writes files that satisfy them."""

SCHEMA = "diffbody.body/1"
TOP_FIELDS = {"schema", "name", "description", "sources", "root_joint", "segments", "spine"}
FEATURE_FIELDS = {"name", "direction"}
LIMIT_FIELDS = {
    "box": {"swing_x_deg", "swing_y_deg", "twist_deg"},
    "cone": {"swing_max_deg", "twist_deg"},
    "hinge": {"swing_y_deg", "twist_deg"},
    "free": set(),
}
OPTIONAL_LIMIT_FIELDS = {"box": {"swing_max_deg"}}
DEFAULT_SWING_MAX_DEG = 179.0
SPINE_SCHEMA = "diffbody.spine/1"
SPINE_ROTATIONS = ("flexion", "axial", "lateral")  # columns of the spine's angle arrays
SPINE_TOP_FIELDS = {"schema", "joints", "vertebrae"}
SPINE_OPTIONAL_FIELDS = {"sources", "angles", "description", "initiator"}
SPINE_JOINT_FIELDS = {
    "name",
    "segment",
    "rest_deg",
    "limits_deg",
    "disc_height_mm",
    "flexion_axis_offset_mm",
}
DEFAULT_SPINE_INITIATOR = "T12_L1"  # the thoracolumbar junction (seed 004's examples)

# Physical ranges (SCHEMA.md): a value outside is a typo or a unit slip (mm for m), and
# float32 kinematics stays finite and well-scaled inside them.
LENGTH_M = (1e-4, 10.0)  # segment lengths and sphere radii
MASS_KG = (0.0, 1000.0)  # massless segments stay legal
POSITION_M = 10.0  # |coordinate| of centroids and sphere origins in the cross of axes
SPINE_ANGLE_DEG = 90.0  # |rest and limit angles| of one intervertebral joint
DISC_HEIGHT_MM = (0.0, 50.0)
AXIS_OFFSET_MM = 100.0  # |flexion-axis offset| from the disc centre
VERTEBRA_SIZE_MM = (1.0, 200.0)
MIN_SWING_MAX_DEG = 1e-3
