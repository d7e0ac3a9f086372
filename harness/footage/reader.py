"""Video files in: what OpenCV can open, checked once, and its frames as BGR arrays.

Stated limits (``VideoInfo`` checks them before any frame is processed): at most ``MAX_SIDE`` pixels a side,
at most ``MAX_FRAMES`` frames, a frame rate in ``(0, MAX_FPS]``, a file of at most ``MAX_FILE_BYTES``. A file
OpenCV cannot open and a file whose first frame it cannot decode (a codec it has no decoder for) are one-line
``VideoInputError``\\ s naming the file.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.errors import HarnessError
from harness.io import check_input_file

MAX_SIDE = 1920                 # px: full HD; larger footage is down-scaled first (features need no more)
MAX_FRAMES = 36_000             # 1 h at 10 fps, 20 min at 30 fps: what one run keeps per person stays small
MAX_FPS = 240.0
MAX_FILE_BYTES = 8 * 2**30


class VideoInputError(HarnessError):
    """A video file that cannot be used (unreadable, a codec OpenCV cannot decode, beyond the stated limits,
    nothing in it to follow)."""


@dataclass(frozen=True)
class VideoInfo:
    """What a video file declares: image size (px), frame rate, frame count (0 when the container does not
    say) and codec (four characters)."""

    path: str
    width: int
    height: int
    fps: float
    frames: int
    codec: str


def _fourcc(value: float) -> str:
    code = int(value) if math.isfinite(value) else 0
    text = "".join(chr((code >> 8 * k) & 0xFF) for k in range(4))
    return text if text.isprintable() and text.strip() else "unknown"


def _avi_codec(path: str | Path) -> str | None:
    """The video codec an AVI file declares (its first video stream header's four characters), or None when
    the file is no AVI: to name the codec of a file OpenCV will not open."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return None
    if head[:4] != b"RIFF" or head[8:12] != b"AVI ":
        return None
    at = head.find(b"strh")             # stream header: "strh", its size (4 bytes), the stream type, the codec
    while at >= 0 and head[at + 8:at + 12] != b"vids":
        at = head.find(b"strh", at + 4)
    if at < 0 or at + 16 > len(head):
        return None
    code = head[at + 12:at + 16]
    return code.decode("latin-1") if code.isalnum() else None


@contextmanager
def _quiet():
    """OpenCV's own log lines off (a file it cannot read is reported once, in one line, by the caller)."""
    import cv2

    previous = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(previous)


def probe(path: str | Path) -> VideoInfo:
    """Open ``path`` with OpenCV, decode its first frame, and check the stated limits."""
    import cv2

    check_input_file(path, VideoInputError, "video", MAX_FILE_BYTES)
    with _quiet():
        cap = cv2.VideoCapture(str(path))
        try:
            if not cap.isOpened():
                codec = _avi_codec(path)
                if codec is not None:
                    raise VideoInputError(f"{path}: OpenCV cannot decode codec {codec} (no decoder for it)")
                raise VideoInputError(f"{path}: OpenCV cannot open it as a video (not a video file, a container "
                                      f"it cannot read, or a codec it has no decoder for)")
            codec = _fourcc(cap.get(cv2.CAP_PROP_FOURCC))
            ok, frame = cap.read()
            if not ok or frame is None:
                raise VideoInputError(f"{path}: OpenCV cannot decode its frames (codec {codec})")
            fps = float(cap.get(cv2.CAP_PROP_FPS))
            count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        finally:
            cap.release()
    height, width = frame.shape[:2]
    if not (math.isfinite(fps) and 0.0 < fps <= MAX_FPS):
        raise VideoInputError(f"{path}: frame rate {fps:g} is not in (0, {MAX_FPS:g}] frames per second")
    if max(width, height) > MAX_SIDE:
        raise VideoInputError(f"{path}: {width}x{height} is larger than {MAX_SIDE} px a side (scale it down first)")
    frames = int(count) if math.isfinite(count) and count > 0 else 0
    if frames > MAX_FRAMES:
        raise VideoInputError(f"{path}: {frames} frames is longer than {MAX_FRAMES} (cut it first)")
    return VideoInfo(str(path), int(width), int(height), fps, frames, codec)


def read_frames(info: VideoInfo) -> Iterator[np.ndarray]:
    """The frames of a probed video, ``(H, W, 3) uint8`` BGR, in order; stops at the first frame OpenCV cannot
    decode (the end, or a damaged tail). More than ``MAX_FRAMES`` frames is a ``VideoInputError``."""
    import cv2

    with _quiet():
        cap = cv2.VideoCapture(info.path)
    try:
        for k in range(MAX_FRAMES + 1):
            ok, frame = cap.read()
            if not ok or frame is None:
                return
            if k == MAX_FRAMES:
                raise VideoInputError(f"{info.path}: longer than {MAX_FRAMES} frames (cut it first)")
            if frame.shape[:2] != (info.height, info.width):
                raise VideoInputError(f"{info.path}: frame {k} is {frame.shape[1]}x{frame.shape[0]}, the video "
                                      f"{info.width}x{info.height}")
            yield frame
    finally:
        cap.release()


def sample_frames(info: VideoInfo, count: int) -> list[np.ndarray]:
    """Up to ``count`` frames spread evenly over the video, to learn its background from.

    Every ``stride``-th frame is kept, and the stride doubles (every other kept frame dropped) whenever more
    than ``2 count`` are held: memory stays bounded whatever the length, declared or not."""
    kept: list[np.ndarray] = []
    stride = 1
    for k, frame in enumerate(read_frames(info)):
        if k % stride == 0:
            kept.append(frame)
            if len(kept) > 2 * count:
                kept = kept[::2]
                stride *= 2
    step = max(1, math.ceil(len(kept) / max(count, 1)))
    return kept[::step]
