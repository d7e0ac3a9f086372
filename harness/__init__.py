"""Monocular whole-body motion recognition and recovery, and the MuJoCo harness that measures it.

Subpackages follow the data flow: ``body`` (the humanoid and its kinematics), ``motion`` (captured and
procedural primitives), ``scene`` (markers, camera, occluders, observations), ``engine`` (the method),
``evaluation`` (scenarios, runner, metrics, reports).
"""

import os

# Offscreen rendering must pick its GL back-end before mujoco is first imported; EGL renders on the CPU
# through Mesa when there is no GPU. A user's own setting wins.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
