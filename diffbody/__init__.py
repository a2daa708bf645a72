"""diffbody: differentiable inverse kinematics for articulated, sphere-skinned bodies.

The core (this folder's modules) holds the body, its one tree walk, the kinematics, the
orientation conventions, limits, postures, local frames, the spine and rendering; each family
of work is a sub-package: `files`, `anthropometry`, `contact`, `ik`, `mocap`, `clouds`, `images`,
`export`, `viewer` and `cli` (docs/design.md, "Families")."""

import importlib
from typing import TYPE_CHECKING

from . import _memory_maps  # noqa: F401  (empties JAX's caches before the map limit crashes XLA)
from ._body import Body, Pose, Spine
from ._descriptors import descriptors
from ._joint_angles import angle_names, joint_angles, opensim_sign
from ._kinematics import Kinematics, forward
from ._limits import STOP_COLUMNS, angles_from_swing, stop_violation, swing_vector, within_limits
from ._local_frames import bone_descriptors, local_frame, local_frames, smooth_reference
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
from ._posture import apply_standard_orientation, pose_from_joint_positions
from ._programs import keep_compiled
from ._render import draw, draw_cloud, render
from ._spine import BendResult, bend_pose, bendspine, movespine, spine_angles, with_spine_angles
from ._streaming import Interrupted

# A later process reads back what this one compiles (docs/design.md, section 3, "Programs").
keep_compiled()

# The families load on first use (PEP 562): `diffbody reach` needs neither the image nor the
# motion-capture code, and importing every family costs a few tenths of a second.
_FAMILIES = {
    "anthropometry": (
        "MEASUREMENT_NAMES",
        "MEASUREMENTS",
        "SCALE_GROUPS",
        "PopulationPrior",
        "PopulationScaling",
        "measure",
        "measurements",
        "scale_body",
        "scale_population",
        "scale_to",
        "scale_to_percentile",
    ),
    "contact": (
        "Contact",
        "ContactReport",
        "Environment",
        "contact_report",
        "sphere_pairs",
    ),
    "export": (
        "SingularJointsWarning",
        "export_mjcf",
        "export_urdf",
        "mujoco_joint_names",
        "mujoco_qpos",
        "mujoco_qpos_slices",
        "urdf_joint_values",
    ),
    "files": (
        "BodyFileError",
        "MotionFileError",
        "PoseFileError",
        "PoseRecord",
        "load_body",
        "load_pose",
        "load_spine",
        "LAB_AXES",
        "MarkerFileError",
        "MarkerSet",
        "MarkerTrial",
        "c3d_screen_axes",
        "load_markerset",
        "load_opensim_markerset",
        "read_c3d",
        "read_ik_tasks",
        "read_markers",
        "read_mot",
        "read_trc",
        "write_trc",
        "save_body",
        "save_pose",
        "write_mot",
    ),
    "clouds": (
        "FitStatus",
        "SphereFit",
        "fit_spheres",
        "fit_spheres_batch",
        "sample_pose",
        "synthetic_cloud",
    ),
    "mocap": (
        "MarkerWarning",
        "MotionFit",
        "StaticFit",
        "TrialsSummary",
        "draw_motion",
        "fit_motion",
        "fit_trials",
        "match_markers",
        "motion_limits",
        "scale_and_register",
        "scale_offsets",
        "world_markers",
    ),
    "ik": ("BatchRun", "ReachResult", "ReachStatus", "Target", "solve_reach", "solve_reach_batch"),
    "images": (
        "ImageSequence",
        "JointTree",
        "Lifting",
        "LiftOptions",
        "LiftStatus",
        "Pinhole",
        "ReflectionChoice",
        "WebbResult",
        "camera_around",
        "choose_reflections",
        "default_joint_tree",
        "draw_bounds",
        "draw_lifting",
        "draw_sequence_fit",
        "image_sequence",
        "joint_centres_from_markers",
        "lift",
        "load_walk_joints",
        "look_at",
        "perpendicular_foot",
        "project",
        "ray_sphere",
        "reaching_motion",
        "read_joint_tree",
        "refine",
        "reprojection_errors",
        "to_camera",
        "true_reflections",
        "walking_motion",
        "webb",
        "write_joint_tree",
    ),
    "viewer": ("Viewer", "animate", "view"),
}
_LAZY = {name: family for family, names in _FAMILIES.items() for name in names}


def __getattr__(name: str):
    """A family's public name or the family itself, imported on first use."""
    if name in _FAMILIES or name == "cli":
        return importlib.import_module(f".{name}", __name__)
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY) | set(_FAMILIES))


if TYPE_CHECKING:  # the same names, for type checkers and editors
    from .anthropometry import (
        MEASUREMENT_NAMES,
        MEASUREMENTS,
        SCALE_GROUPS,
        PopulationPrior,
        PopulationScaling,
        measure,
        measurements,
        scale_body,
        scale_population,
        scale_to,
        scale_to_percentile,
    )
    from .clouds import (
        FitStatus,
        SphereFit,
        fit_spheres,
        fit_spheres_batch,
        sample_pose,
        synthetic_cloud,
    )
    from .contact import (
        Contact,
        ContactReport,
        Environment,
        contact_report,
        sphere_pairs,
    )
    from .export import (
        SingularJointsWarning,
        export_mjcf,
        export_urdf,
        mujoco_joint_names,
        mujoco_qpos,
        mujoco_qpos_slices,
        urdf_joint_values,
    )
    from .files import (
        LAB_AXES,
        BodyFileError,
        MarkerFileError,
        MarkerSet,
        MarkerTrial,
        MotionFileError,
        PoseFileError,
        PoseRecord,
        c3d_screen_axes,
        load_body,
        load_markerset,
        load_opensim_markerset,
        load_pose,
        load_spine,
        read_c3d,
        read_ik_tasks,
        read_markers,
        read_mot,
        read_trc,
        save_body,
        save_pose,
        write_mot,
        write_trc,
    )
    from .ik import BatchRun, ReachResult, ReachStatus, Target, solve_reach, solve_reach_batch
    from .images import (
        ImageSequence,
        JointTree,
        Lifting,
        LiftOptions,
        LiftStatus,
        Pinhole,
        ReflectionChoice,
        WebbResult,
        camera_around,
        choose_reflections,
        default_joint_tree,
        draw_bounds,
        draw_lifting,
        draw_sequence_fit,
        image_sequence,
        joint_centres_from_markers,
        lift,
        load_walk_joints,
        look_at,
        perpendicular_foot,
        project,
        ray_sphere,
        reaching_motion,
        read_joint_tree,
        refine,
        reprojection_errors,
        to_camera,
        true_reflections,
        walking_motion,
        webb,
        write_joint_tree,
    )
    from .mocap import (
        MarkerWarning,
        MotionFit,
        StaticFit,
        TrialsSummary,
        draw_motion,
        fit_motion,
        fit_trials,
        match_markers,
        motion_limits,
        scale_and_register,
        scale_offsets,
        world_markers,
    )
    from .viewer import Viewer, animate, view

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
    # Pose files
    "PoseFileError",
    "PoseRecord",
    "load_pose",
    "save_pose",
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
    # Contact and balance
    "Contact",
    "ContactReport",
    "Environment",
    "contact_report",
    "sphere_pairs",
    "ReachResult",
    "ReachStatus",
    "Target",
    "solve_reach",
    "solve_reach_batch",
    # Long runs: a batch written to a file as it goes
    "BatchRun",
    "Interrupted",
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
    "c3d_screen_axes",
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
    "fit_trials",
    "TrialsSummary",
    "draw_motion",
    "descriptors",
    "motion_limits",
    # Motion capture: OpenSim's files and joint angles
    "load_opensim_markerset",
    "read_ik_tasks",
    "joint_angles",
    "angle_names",
    "opensim_sign",
    "MotionFileError",
    "read_mot",
    "write_mot",
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
    "draw_sequence_fit",
    "reprojection_errors",
    # Export
    "export_mjcf",
    "export_urdf",
    "mujoco_joint_names",
    "mujoco_qpos",
    "mujoco_qpos_slices",
    "SingularJointsWarning",
    "urdf_joint_values",
    # Viewing and animations
    "Viewer",
    "view",
    "animate",
    # Rendering
    "draw",
    "draw_cloud",
    "render",
]
