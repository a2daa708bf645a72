"""diffbody: differentiable inverse kinematics for articulated, sphere-skinned bodies."""

from ._batch import solve_reach_batch as solve_reach_batch
from ._body import Body as Body
from ._body import Pose as Pose
from ._export import (
    export_mjcf as export_mjcf,
)
from ._export import (
    export_urdf as export_urdf,
)
from ._export import (
    mujoco_joint_names as mujoco_joint_names,
)
from ._export import (
    mujoco_qpos as mujoco_qpos,
)
from ._export import (
    urdf_joint_values as urdf_joint_values,
)
from ._kinematics import Kinematics as Kinematics
from ._kinematics import forward as forward
from ._limits import (
    STOP_COLUMNS as STOP_COLUMNS,
)
from ._limits import (
    angles_from_swing as angles_from_swing,
)
from ._limits import (
    stop_violation as stop_violation,
)
from ._limits import (
    swing_vector as swing_vector,
)
from ._limits import (
    within_limits as within_limits,
)
from ._loading import BodyFileError as BodyFileError
from ._loading import load_body as load_body
from ._local_frames import (
    bone_descriptors as bone_descriptors,
)
from ._local_frames import (
    local_frame as local_frame,
)
from ._local_frames import (
    local_frames as local_frames,
)
from ._local_frames import (
    smooth_reference as smooth_reference,
)
from ._orientation import (
    azimuth_polar_to_inclination_azimuth as azimuth_polar_to_inclination_azimuth,
)
from ._orientation import (
    azimuth_polar_to_vector as azimuth_polar_to_vector,
)
from ._orientation import (
    inclination_azimuth_to_azimuth_polar as inclination_azimuth_to_azimuth_polar,
)
from ._orientation import (
    inclination_azimuth_to_vector as inclination_azimuth_to_vector,
)
from ._orientation import (
    orientation_matrix as orientation_matrix,
)
from ._orientation import (
    standard_frame as standard_frame,
)
from ._orientation import (
    standard_twist as standard_twist,
)
from ._orientation import (
    vector_to_azimuth_polar as vector_to_azimuth_polar,
)
from ._orientation import (
    vector_to_inclination_azimuth as vector_to_inclination_azimuth,
)
from ._posture import (
    apply_standard_orientation as apply_standard_orientation,
)
from ._posture import (
    pose_from_joint_positions as pose_from_joint_positions,
)
from ._reach import ReachResult as ReachResult
from ._reach import Target as Target
from ._reach import solve_reach as solve_reach
from ._render import draw as draw
from ._render import render as render
from ._spine import (
    BendResult as BendResult,
)
from ._spine import (
    Spine as Spine,
)
from ._spine import (
    bend_pose as bend_pose,
)
from ._spine import (
    bendspine as bendspine,
)
from ._spine import (
    load_spine as load_spine,
)
from ._spine import (
    movespine as movespine,
)
from ._spine import (
    spine_angles as spine_angles,
)
from ._spine import (
    with_spine_angles as with_spine_angles,
)

__version__ = "0.1.0"
