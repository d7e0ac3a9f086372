"""The simulator side: markers, camera, occluders, visibility and the observations one camera makes."""

from harness.scene.spec import CameraSpec
from harness.scene.spec import MarkerSpec
from harness.scene.spec import ObservationSpec
from harness.scene.spec import OccluderSpec
from harness.scene.spec import SceneError
from harness.scene.spec import SceneSpec

__all__ = ["CameraSpec", "MarkerSpec", "ObservationSpec", "OccluderSpec", "SceneError", "SceneSpec"]
