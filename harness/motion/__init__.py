"""Motion primitives: the ``Motion`` type and its sources (procedural performer, captured motion)."""

from harness.motion.motion import Motion
from harness.motion.motion import MotionError
from harness.motion.motion import MotionVelocities

__all__ = ["Motion", "MotionError", "MotionVelocities"]
