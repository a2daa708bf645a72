"""Exports to robotics formats: the body as rigid links (MJCF for MuJoCo, URDF), and poses
as their joint values."""

from ._mjcf import (
    SingularJointsWarning as SingularJointsWarning,
)
from ._mjcf import (
    export_mjcf as export_mjcf,
)
from ._mjcf import (
    mujoco_joint_names as mujoco_joint_names,
)
from ._mjcf import (
    mujoco_qpos as mujoco_qpos,
)
from ._mjcf import (
    mujoco_qpos_slices as mujoco_qpos_slices,
)
from ._urdf import (
    export_urdf as export_urdf,
)
from ._urdf import (
    urdf_joint_values as urdf_joint_values,
)
