"""Video mode: the subject rendered in cloth (``harness.scene.texture``) and its flows found by ``track-video``'s
own pipeline (``harness.footage.pipeline``), so that the harness measures what image processing costs beside the
geometric flows of the same runs.

The pipeline learns the background from the scene rendered without the subject (an empty plate: a static
camera's background before anyone walks in), and follows the whole image as one region (``--roi`` of the
whole frame): the scene holds one person, so everything that moves is them. Its flows are the observation;
features are no markers, so every row's ground-truth marker id is ``FEATURE_ID`` (-2; outliers added later
are -1).
"""

from __future__ import annotations

import numpy as np

from harness.footage.pipeline import FollowResult, follow_people
from harness.scene.rendered import render_frames
from harness.scene.setup import SceneSetup

FEATURE_ID = -2          # the ground-truth "marker id" of a video feature: no marker, and no outlier either


def render_footage(setup: SceneSetup, qpos: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The textured frames ``(T)`` of ``(H, W, 3) uint8`` BGR (OpenCV's order, as a video file gives them) and
    the empty plate ``(H, W, 3)``. The scene of ``setup`` must have been built textured (mode ``video``)."""
    import cv2

    plate = next(render_frames(setup, qpos[:1], dots=False, body=False))
    frames = [cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) for rgb in render_frames(setup, qpos, dots=False)]
    return frames, cv2.cvtColor(plate, cv2.COLOR_RGB2BGR)


def follow_subject(frames: list[np.ndarray], plate: np.ndarray, fps: float) -> FollowResult:
    """``track-video``'s pipeline on rendered footage: background from the plate, the whole frame one region."""
    h, w = plate.shape[:2]
    return follow_people(frames, fps, [plate], roi=(0, 0, w, h))


def video_flows(setup: SceneSetup, qpos: np.ndarray, fps: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame ``(rows (M, 4), marker ids (M,) all FEATURE_ID)``: the subject's flows from rendered textured
    footage (unshuffled, no dropout)."""
    frames, plate = render_footage(setup, qpos)
    result = follow_subject(frames, plate, fps)
    empty = np.empty((0, 4))
    person = result.people[0] if result.people else None
    out = []
    for t in range(len(qpos)):
        rows = person.flows.get(t, empty) if person is not None else empty
        out.append((rows, np.full(len(rows), FEATURE_ID, dtype=int)))
    return out
