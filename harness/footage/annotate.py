"""The annotated video of ``track-video``: over each frame, every followed person's box and identity, their
flows, the engine's class and confidence at that frame, and the recovered body drawn as a skeleton."""

from __future__ import annotations

import numpy as np

from harness.footage.pipeline import FollowResult, PersonTrack
from harness.pinhole import Intrinsics

ARROW_FRAMES = 3.0        # a flow arrow shows this many frames of the feature's motion (one is 1-3 px here)
SKELETON_RGB = (255, 60, 230)
FLOW_RGB = (255, 230, 0)
TEXT_SCALE = 0.45


def person_colour(person: int) -> tuple[int, int, int]:
    """A bright RGB colour of its own for each person id (golden-angle hues)."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((person * 0.618034) % 1.0, 0.75, 1.0)
    return int(255 * r), int(255 * g), int(255 * b)


def _text(img: np.ndarray, text: str, org: tuple[int, int], rgb) -> None:
    import cv2

    x, y = org
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, TEXT_SCALE, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, TEXT_SCALE, rgb, 1, cv2.LINE_AA)


def annotate_frame(rgb: np.ndarray, t: int, result: FollowResult, estimates: dict, joints: dict,
                   intr: Intrinsics, parents: np.ndarray) -> np.ndarray:
    """Frame ``t`` (RGB ``(H, W, 3) uint8``) with every person present drawn on a copy.

    estimates: ``{person id: Estimate}`` of the people the engine ran on; joints: ``{person id: (T_p, J, 3)}``
    their recovered joint centres in the camera frame (m); parents: ``(J,)`` each joint's parent (-1: root).
    """
    import cv2

    from harness.pinhole import project
    from harness.video import draw_skeleton

    img = np.ascontiguousarray(rgb.copy())
    for person in result.people:
        if not person.first <= t <= person.last:
            continue
        colour = person_colour(person.id)
        k = t - person.first
        if person.id in joints:
            j = joints[person.id][k]
            front = j[:, 2] > 0.05
            draw_skeleton(img, project(intr, np.where(front[:, None], j, 1.0)), parents, SKELETON_RGB, front, 1)
        for u, v, du, dv in person.flows.get(t, np.empty((0, 4))):
            start = (int(round(u - du * ARROW_FRAMES / result.fps)), int(round(v - dv * ARROW_FRAMES / result.fps)))
            cv2.arrowedLine(img, start, (int(round(u)), int(round(v))), FLOW_RGB, 1, cv2.LINE_AA, tipLength=0.3)
        box = person.boxes.get(t)
        label = f"#{person.id}"
        if person.id in estimates:
            post = estimates[person.id].class_posterior[k]
            best = int(np.argmax(post))
            label += f" {estimates[person.id].classes[best]} {post[best]:.2f}"
        if box is None:
            label += " (in a group)" if t in person.grouped else " (unseen)"
            box = _last_box(person, t)
            if box is None:
                continue
        x, y, w, h = (int(round(v)) for v in box)
        if t in person.boxes:
            cv2.rectangle(img, (x, y), (x + w, y + h), colour, 1)
        _text(img, label, (x, max(y - 4, 12)), colour)
        if person.id in estimates:           # the answer's confidence as a bar under the box
            conf = float(estimates[person.id].class_posterior[k].max())
            cv2.rectangle(img, (x, y + h + 2), (x + max(1, int(round(w * conf))), y + h + 5), colour, -1)
    _text(img, f"frame {t}  {t / result.fps:6.1f} s   arrows: {ARROW_FRAMES:g} frames of motion; magenta: "
               f"recovered body", (6, 16), (255, 255, 255))
    return img


def _last_box(person: PersonTrack, t: int) -> np.ndarray | None:
    seen = [s for s in person.boxes if s <= t]
    return person.boxes[max(seen)] if seen else None
