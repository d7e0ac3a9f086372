"""The humanoid56 body model and its kinematics (arrays in, arrays out)."""

from harness.body.kinematics import body_frames
from harness.body.kinematics import body_origins
from harness.body.kinematics import forward_points
from harness.body.kinematics import forward_points_and_jacobians
from harness.body.kinematics import geom_z_range
from harness.body.kinematics import point_jacobians
from harness.body.kinematics import point_velocities
from harness.body.model import DEFAULT_MODEL_PATH
from harness.body.model import N_ANGLES
from harness.body.model import BodyModel
from harness.body.model import load_mjmodel
from harness.body.model import nominal_body
from harness.body.surface import SurfacePoints
from harness.body.surface import sample_surface

__all__ = [
    "BodyModel", "DEFAULT_MODEL_PATH", "N_ANGLES", "SurfacePoints", "body_frames", "body_origins", "forward_points",
    "forward_points_and_jacobians", "geom_z_range", "load_mjmodel", "nominal_body", "point_jacobians", "point_velocities", "sample_surface",
]
