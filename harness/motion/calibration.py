"""The performer's calibration on real captures: per primitive, what brings its joint-angle statistics to the
captures' (the table itself is data, ``calibration.json`` beside this module).

Per class (``ClassCalibration``):

- ``posture`` ``(50,)`` degrees (model sign convention) added to every frame, on top of the subject's own
  posture: the class's carriage (a fighting stance's bent knees and raised elbows, a pronated forearm);
- ``gain`` ``(50,)``: multiplies every movement the primitive writes into each joint (the range of motion);
- ``lean`` and ``lean_gain`` (pitch, roll): the same for the base's tilt (degrees; pitch > 0 tips the pelvis
  forward, roll > 0 lowers its right side), which carries much of a bow or a crouch;
- ``extent``: multiplies the durations of a discrete primitive's phases and the number of cycles of a cyclic
  one (timing; the cycle period is kept);
- ``left``: the share of subjects who perform the primitive with the left side (left/right use); a subject
  whose fixed laterality (``performer.SubjectStyle.laterality``, uniform in [0, 1)) is below it mirrors
  the primitive.

``NEUTRAL`` (zero posture, unit gains and extent, the performer's default left share) is the performer as
written by hand. The table is fitted by ``harness.motion.realism.fit_calibration`` on the calibration
subjects of a capture set and written by ``benchmarks/performer_realism.py --fit``; the same script reports
how far the procedural joint-angle distributions are from the other subjects' before and after.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from harness.body.model import N_ANGLES
from harness.errors import HarnessError
from harness.io import write_text_atomic

CALIBRATION_PATH = Path(__file__).with_name("calibration.json")
#: Share of left-sided performers of a primitive without a measured left/right use.
DEFAULT_LEFT = 0.2


class CalibrationError(HarnessError):
    """A calibration table that cannot be read; names the file and the class or key."""


@dataclass(frozen=True)
class ClassCalibration:
    """One primitive's calibration (module docstring): posture ``(50,)`` deg, gain ``(50,)``, lean ``(2,)``
    deg and lean_gain ``(2,)`` (pitch, roll), extent, left."""

    posture: np.ndarray
    gain: np.ndarray
    lean: np.ndarray = field(default_factory=lambda: np.zeros(2))
    lean_gain: np.ndarray = field(default_factory=lambda: np.ones(2))
    extent: float = 1.0
    left: float = DEFAULT_LEFT

    def to_json(self) -> dict:
        r = lambda v, d: [round(float(x), d) for x in v]  # noqa: E731
        return {"posture": r(self.posture, 3), "gain": r(self.gain, 4), "lean": r(self.lean, 3),
                "lean_gain": r(self.lean_gain, 4), "extent": round(float(self.extent), 4),
                "left": round(float(self.left), 4)}


NEUTRAL = ClassCalibration(np.zeros(N_ANGLES), np.ones(N_ANGLES))


def save_calibration(path: str | Path, table: dict[str, ClassCalibration], about: dict | None = None) -> None:
    """Write ``table`` (class -> calibration) as JSON, atomically; ``about`` records how it was fitted."""
    # One line per array, so that a refit reads as a diff of numbers.
    classes = ",\n".join(f'  {json.dumps(c)}: {{\n' + ",\n".join(f"    {json.dumps(k)}: {json.dumps(v)}"
                                                              for k, v in cal.to_json().items()) + "\n  }"
                         for c, cal in table.items())
    text = f'{{\n "about": {json.dumps(about or {})},\n "classes": {{\n{classes}\n }}\n}}\n'
    write_text_atomic(path, text)


def read_calibration(path: str | Path) -> dict[str, ClassCalibration]:
    """Read a calibration table written by ``save_calibration``; errors name the file and the entry."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such calibration file") from None
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{path}: not a calibration table ({exc})") from None
    out = {}
    for label, entry in (doc.get("classes") or {}).items():
        try:
            posture = np.asarray(entry["posture"], dtype=float)
            gain = np.asarray(entry["gain"], dtype=float)
            lean, lean_gain = np.asarray(entry["lean"], dtype=float), np.asarray(entry["lean_gain"], dtype=float)
            extent, left = float(entry["extent"]), float(entry["left"])
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"{path}: class {label!r}: malformed entry ({exc})") from None
        if posture.shape != (N_ANGLES,) or gain.shape != (N_ANGLES,) or lean.shape != (2,) or lean_gain.shape != (2,):
            raise CalibrationError(f"{path}: class {label!r}: posture and gain need {N_ANGLES} values each, "
                                   f"lean and lean_gain 2")
        if not (extent > 0 and 0.0 <= left <= 1.0 and np.all(gain >= 0) and np.all(lean_gain >= 0)):
            raise CalibrationError(f"{path}: class {label!r}: extent must be positive, left in [0, 1], gains >= 0")
        out[label] = ClassCalibration(posture, gain, lean, lean_gain, extent, left)
    return out


@lru_cache(maxsize=1)
def default_calibration() -> dict[str, ClassCalibration]:
    """The table shipped with the performer (``CALIBRATION_PATH``); classes it lacks are ``NEUTRAL``."""
    return read_calibration(CALIBRATION_PATH) if CALIBRATION_PATH.is_file() else {}
