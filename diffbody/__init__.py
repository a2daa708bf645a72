"""diffbody: differentiable inverse kinematics for articulated, sphere-skinned bodies."""

from ._anthropometry import (
    PopulationScaling,
    scale_population,
    scale_to,
    scale_to_percentile,
)
from ._batch import solve_reach_batch
from ._body import Body, Pose, Spine
from ._clouds import sample_pose, synthetic_cloud
from ._data_files import BodyFileError
from ._descriptors import descriptors
from ._fitting import FitStatus, SphereFit, fit_spheres, fit_spheres_batch
from ._joint_centres import joint_centres_from_markers, load_walk_joints
from ._joint_tree import JointTree, default_joint_tree, read_joint_tree, write_joint_tree
from ._kinematics import Kinematics, forward
from ._lifting import Lifting, LiftOptions, LiftStatus, lift, refine
from ._limits import STOP_COLUMNS, angles_from_swing, stop_violation, swing_vector, within_limits
from ._loading import load_body
from ._local_frames import bone_descriptors, local_frame, local_frames, smooth_reference
from ._markers import (
    LAB_AXES,
    MarkerFileError,
    MarkerTrial,
    read_c3d,
    read_markers,
    read_trc,
    write_trc,
)
from ._markerset import (
    MarkerSet,
    MarkerWarning,
    load_markerset,
    match_markers,
    scale_offsets,
    world_markers,
)
from ._measurements import MEASUREMENT_NAMES, MEASUREMENTS, measure, measurements
from ._mjcf import export_mjcf, mujoco_joint_names, mujoco_qpos
from ._mocap import MotionFit, StaticFit, fit_motion, scale_and_register
from ._motions import reaching_motion, walking_motion
from ._orientation import (
    azimuth_polar_to_inclination_azimuth,
    azimuth_polar_to_vector,
    inclination_azimuth_to_azimuth_polar,
    inclination_azimuth_to_vector,
    orientation_matrix,
    standard_frame,
    standard_twist,
    vector_to_azimuth_polar,
    vector_to_inclination_azimuth,
)
from ._pinhole import (
    ImageSequence,
    Pinhole,
    camera_around,
    image_sequence,
    look_at,
    project,
    to_camera,
)
from ._posture import apply_standard_orientation, pose_from_joint_positions
from ._prior import PopulationPrior
from ._reach import ReachResult, ReachStatus, solve_reach
from ._reflections import ReflectionChoice, choose_reflections
from ._render import draw, draw_cloud, render
from ._saving import save_body
from ._scaling import SCALE_GROUPS, scale_body
from ._sequence_plots import draw_bounds, draw_lifting
from ._spine import BendResult, bend_pose, bendspine, movespine, spine_angles, with_spine_angles
from ._spine_file import load_spine
from ._targets import Target
from ._urdf import export_urdf, urdf_joint_values
from ._webb import WebbResult, perpendicular_foot, ray_sphere, true_reflections, webb

__version__ = "0.1.0"

__all__ = [
    # Body & loading
    "Body",
    "Pose",
    "Spine",
    "BodyFileError",
    "load_body",
    "load_spine",
    "save_body",
    # Kinematics
    "Kinematics",
    "forward",
    "pose_from_joint_positions",
    # Orientation & local frames
    "azimuth_polar_to_inclination_azimuth",
    "azimuth_polar_to_vector",
    "inclination_azimuth_to_azimuth_polar",
    "inclination_azimuth_to_vector",
    "vector_to_azimuth_polar",
    "vector_to_inclination_azimuth",
    "orientation_matrix",
    "standard_frame",
    "standard_twist",
    "apply_standard_orientation",
    "bone_descriptors",
    "local_frame",
    "local_frames",
    "smooth_reference",
    # Limits
    "STOP_COLUMNS",
    "angles_from_swing",
    "stop_violation",
    "swing_vector",
    "within_limits",
    # Spine
    "BendResult",
    "bend_pose",
    "bendspine",
    "movespine",
    "spine_angles",
    "with_spine_angles",
    # Reach
    "ReachResult",
    "ReachStatus",
    "Target",
    "solve_reach",
    "solve_reach_batch",
    # Anthropometry
    "MEASUREMENTS",
    "MEASUREMENT_NAMES",
    "measure",
    "measurements",
    "PopulationPrior",
    "PopulationScaling",
    "SCALE_GROUPS",
    "scale_body",
    "scale_population",
    "scale_to",
    "scale_to_percentile",
    # Sphere-cloud fitting
    "FitStatus",
    "SphereFit",
    "fit_spheres",
    "fit_spheres_batch",
    "sample_pose",
    "synthetic_cloud",
    # Motion capture: marker files and marker sets
    "LAB_AXES",
    "MarkerFileError",
    "MarkerTrial",
    "read_c3d",
    "read_markers",
    "read_trc",
    "write_trc",
    "MarkerSet",
    "MarkerWarning",
    "load_markerset",
    "match_markers",
    "scale_offsets",
    "world_markers",
    "StaticFit",
    "MotionFit",
    "scale_and_register",
    "fit_motion",
    "descriptors",
    # Image sequences (seed 003)
    "JointTree",
    "default_joint_tree",
    "read_joint_tree",
    "write_joint_tree",
    "Pinhole",
    "ImageSequence",
    "look_at",
    "camera_around",
    "to_camera",
    "project",
    "image_sequence",
    "walking_motion",
    "reaching_motion",
    "WebbResult",
    "webb",
    "perpendicular_foot",
    "ray_sphere",
    "true_reflections",
    "ReflectionChoice",
    "choose_reflections",
    "LiftOptions",
    "LiftStatus",
    "Lifting",
    "refine",
    "lift",
    "joint_centres_from_markers",
    "load_walk_joints",
    "draw_lifting",
    "draw_bounds",
    # Export
    "export_mjcf",
    "export_urdf",
    "mujoco_joint_names",
    "mujoco_qpos",
    "urdf_joint_values",
    # Rendering
    "draw",
    "draw_cloud",
    "render",
]
