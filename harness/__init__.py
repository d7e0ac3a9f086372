"""Monocular whole-body motion recognition and recovery, and the MuJoCo harness that measures it.

Subpackages follow the data flow: ``body`` (the humanoid and its kinematics), ``motion`` (captured and
procedural primitives), ``scene`` (markers, camera, occluders, observations), ``engine`` (the method),
``evaluation`` (scenarios, runner, metrics, reports).
"""

__version__ = "0.1.0"
