"""Image sequences (Webb, "Static Analysis of Moving Jointed Objects"): the observed joint
tree, the pinhole camera, Webb's lengths from 2D joints, reflections chosen by continuity,
the joint refinement, the population prior on part lengths, several cameras (calibrated or not),
synthetic motions and the pictures of a sequence."""

from ._affine_views import (
    AffineLifting as AffineLifting,
)
from ._affine_views import (
    lift_views_uncalibrated as lift_views_uncalibrated,
)
from ._joint_centres import (
    joint_centres_from_markers as joint_centres_from_markers,
)
from ._joint_centres import (
    load_walk_joints as load_walk_joints,
)
from ._joint_tree import (
    JointTree as JointTree,
)
from ._joint_tree import (
    default_joint_tree as default_joint_tree,
)
from ._joint_tree import (
    read_joint_tree as read_joint_tree,
)
from ._joint_tree import (
    write_joint_tree as write_joint_tree,
)
from ._length_prior import (
    LengthPrior as LengthPrior,
)
from ._length_prior import (
    length_prior as length_prior,
)
from ._lifting import (
    Lifting as Lifting,
)
from ._lifting import (
    LiftOptions as LiftOptions,
)
from ._lifting import (
    lift as lift,
)
from ._lifting import (
    refine as refine,
)
from ._motions import (
    reaching_motion as reaching_motion,
)
from ._motions import (
    walking_motion as walking_motion,
)
from ._pinhole import (
    ImageSequence as ImageSequence,
)
from ._pinhole import (
    Pinhole as Pinhole,
)
from ._pinhole import (
    camera_around as camera_around,
)
from ._pinhole import (
    image_sequence as image_sequence,
)
from ._pinhole import (
    look_at as look_at,
)
from ._pinhole import (
    project as project,
)
from ._pinhole import (
    to_camera as to_camera,
)
from ._reflections import (
    ReflectionChoice as ReflectionChoice,
)
from ._reflections import (
    choose_reflections as choose_reflections,
)
from ._sequence_plots import (
    draw_bounds as draw_bounds,
)
from ._sequence_plots import (
    draw_lifting as draw_lifting,
)
from ._sequence_plots import (
    draw_sequence_fit as draw_sequence_fit,
)
from ._sequence_plots import (
    reprojection_errors as reprojection_errors,
)
from ._views import (
    ViewsLifting as ViewsLifting,
)
from ._views import (
    lift_views as lift_views,
)
from ._views import (
    stack_cameras as stack_cameras,
)
from ._views import (
    triangulate as triangulate,
)
from ._webb import (
    WebbResult as WebbResult,
)
from ._webb import (
    perpendicular_foot as perpendicular_foot,
)
from ._webb import (
    ray_sphere as ray_sphere,
)
from ._webb import (
    true_reflections as true_reflections,
)
from ._webb import (
    webb as webb,
)
