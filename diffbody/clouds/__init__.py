"""Sphere clouds: a body's dimensions and posture fitted to a measured cloud of spheres (one
cloud or a batch), and synthetic clouds to test it on."""

from .._solver import FitStatus as FitStatus  # every fit's status (mocap's, lifting's too)
from ._cloud_fit import SphereFit as SphereFit
from ._cloud_fit import fit_spheres as fit_spheres
from ._cloud_fit import fit_spheres_batch as fit_spheres_batch
from ._clouds import sample_pose as sample_pose
from ._clouds import synthetic_cloud as synthetic_cloud
