"""diffbody: differentiable inverse kinematics for articulated, sphere-skinned bodies."""

from ._body import Body as Body, Pose as Pose
from ._kinematics import Kinematics as Kinematics, forward as forward
from ._limits import (
    STOP_COLUMNS as STOP_COLUMNS,
    angles_from_swing as angles_from_swing,
    stop_violation as stop_violation,
    swing_vector as swing_vector,
    within_limits as within_limits,
)
from ._loading import BodyFileError as BodyFileError, load_body as load_body
from ._local_frames import (
    bone_descriptors as bone_descriptors,
    local_frame as local_frame,
    local_frames as local_frames,
    smooth_reference as smooth_reference,
)
from ._orientation import (
    azimuth_polar_to_inclination_azimuth as azimuth_polar_to_inclination_azimuth,
    azimuth_polar_to_vector as azimuth_polar_to_vector,
    inclination_azimuth_to_azimuth_polar as inclination_azimuth_to_azimuth_polar,
    inclination_azimuth_to_vector as inclination_azimuth_to_vector,
    orientation_matrix as orientation_matrix,
    standard_frame as standard_frame,
    standard_twist as standard_twist,
    vector_to_azimuth_polar as vector_to_azimuth_polar,
    vector_to_inclination_azimuth as vector_to_inclination_azimuth,
)
from ._posture import (
    apply_standard_orientation as apply_standard_orientation,
    pose_from_joint_positions as pose_from_joint_positions,
)
from ._render import render as render

__version__ = "0.1.0"
