"""The engine: motion database, its transformation into the image, the particle filter, recognition and
recovery. It reads observations, intrinsics, the body model and the database only; it imports nothing from
the scene or the evaluation packages (a test checks this)."""

from harness.engine.database import MotionDatabase
from harness.engine.features import motion_features
from harness.engine.recognition import Recognizer
from harness.engine.recognition import recognize_features
from harness.engine.estimate import Estimate
from harness.engine.tracker import Tracker
from harness.engine.config import TrackerConfig

__all__ = ["Estimate", "MotionDatabase", "Recognizer", "Tracker", "TrackerConfig", "motion_features",
           "recognize_features"]
