"""Video input: people in a static camera's footage found by background subtraction, followed from frame to frame,
sparse features on each tracked by pyramidal Lucas-Kanade, and each person's flows as the engine's observation
(``harness track-video``; docs/video.md). Imports nothing from the scene or the evaluation: real footage has
neither."""

from harness.footage.pipeline import FollowResult
from harness.footage.pipeline import PersonTrack
from harness.footage.pipeline import follow_people
from harness.footage.reader import VideoInfo
from harness.footage.reader import VideoInputError
from harness.footage.reader import probe
from harness.footage.reader import read_frames
from harness.footage.reader import sample_frames

__all__ = ["FollowResult", "PersonTrack", "VideoInfo", "VideoInputError", "follow_people", "probe", "read_frames",
           "sample_frames"]
