"""BVH motion files: parser and forward kinematics.

A BVH file declares a joint tree (``ROOT``/``JOINT``/``End Site`` blocks with an ``OFFSET`` and, for joints,
``CHANNELS``) and then ``MOTION``: a frame count, a frame time and one line of channel values per frame.
Rotation channels are degrees; a joint's local rotation is the product of its rotation channels in the
order they are declared, ``R = R_c1 R_c2 R_c3`` (column vectors), so ``Zrotation Yrotation Xrotation``
is ``Rz Ry Rx``. Forward kinematics, per joint with parent ``p``:

    W_j = W_p R_j,        x_j = x_p + W_p (offset_j + t_j)

with ``t_j`` the joint's own position channels (zero for joints without any). End sites are kept as extra
joints named ``<parent>_end`` with no channels. CR, LF and CRLF line endings (mixed too) are accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.errors import HarnessError
from harness.io import read_text

#: Metres per BVH unit in the CMU conversions: they keep the lengths of CMU's ASF files, whose
#: ``:units length 0.45`` makes one unit 1/0.45 inch.
CMU_BVH_UNIT_M = 0.0254 / 0.45

ROTATION_CHANNELS = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
POSITION_CHANNELS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


class BvhError(HarnessError):
    """A BVH file that cannot be read; the message names the file, the line and the problem."""


@dataclass(frozen=True)
class BvhClip:
    """A parsed BVH file.

    names: ``(J,)`` joint names (end sites as ``<parent>_end``). parents: ``(J,)`` parent index, -1 for the
    root. offsets: ``(J, 3)`` in file units. channels: per joint, the channel names in declared order
    (empty for end sites). frame_time: seconds. frames: ``(T, C)`` channel values, C the total channel count,
    joints' channels concatenated in declaration order (degrees for rotations, file units for positions).
    path: where it was read from.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    frames: np.ndarray
    path: Path | None = None

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def channel_offsets(self) -> np.ndarray:
        """Index of each joint's first channel in a frame row, ``(J,)``."""
        counts = np.array([len(c) for c in self.channels], dtype=int)
        return np.concatenate([[0], np.cumsum(counts)[:-1]])

    def positions(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """World joint positions ``(T, J, 3)`` in file units for frames ``[start, stop)``."""
        return bvh_forward_kinematics(self, self.frames[start:stop])


def axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` about coordinate axis 0, 1 or 2 by ``angle`` (radians, ``(...)``)."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def bvh_forward_kinematics(clip: BvhClip, frames: np.ndarray) -> np.ndarray:
    """World positions ``(T, J, 3)`` (file units) of every joint for channel rows ``frames (T, C)``."""
    frames = np.atleast_2d(np.asarray(frames, dtype=float))
    n = len(frames)
    first = clip.channel_offsets()
    rot = np.empty((len(clip.names), n, 3, 3))
    pos = np.empty((n, len(clip.names), 3))
    for j, (parent, chans) in enumerate(zip(clip.parents, clip.channels)):
        local_r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        local_t = np.broadcast_to(clip.offsets[j], (n, 3)).copy()
        for k, name in enumerate(chans):
            values = frames[:, first[j] + k]
            if name in ROTATION_CHANNELS:
                local_r = local_r @ axis_rotation(ROTATION_CHANNELS[name], np.deg2rad(values))
            else:
                local_t[:, POSITION_CHANNELS[name]] += values
        if parent < 0:
            rot[j], pos[:, j] = local_r, local_t
        else:
            rot[j] = rot[parent] @ local_r
            pos[:, j] = pos[:, parent] + np.einsum("tij,tj->ti", rot[parent], local_t)
    return pos


class _Lines:
    """Tokenised non-empty lines with their 1-based numbers, for error messages."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.items = [(i + 1, line.split()) for i, line in enumerate(text.splitlines()) if line.strip()]
        self.pos = 0

    def error(self, line: int | None, problem: str) -> BvhError:
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        return BvhError(f"{where}: {problem}")

    def next(self, expecting: str) -> tuple[int, list[str]]:
        if self.pos >= len(self.items):
            last = self.items[-1][0] if self.items else 0
            raise self.error(last, f"truncated file: end of file while expecting {expecting}")
        item = self.items[self.pos]
        self.pos += 1
        return item


def _floats(lines: _Lines, line: int, tokens: list[str], what: str) -> list[float]:
    try:
        return [float(t) for t in tokens]
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise lines.error(line, f"non-numeric value {bad!r} in {what}") from None


def _is_float(token: str) -> bool:
    try:
        float(token)
        return True
    except ValueError:
        return False


def _parse_joint(lines: _Lines, name: str, parent: int, out: dict, is_end: bool) -> None:
    index = len(out["names"])
    out["names"].append(name)
    out["parents"].append(parent)
    out["offsets"].append(np.zeros(3))
    out["channels"].append(())
    line, tok = lines.next("'{'")
    if tok != ["{"]:
        raise lines.error(line, f"expected '{{' after joint {name!r}, found {' '.join(tok)!r}")
    while True:
        line, tok = lines.next(f"'}}' closing joint {name!r}")
        key = tok[0]
        if key == "OFFSET":
            if len(tok) != 4:
                raise lines.error(line, f"OFFSET of {name!r} needs 3 values, found {len(tok) - 1}")
            out["offsets"][index] = np.array(_floats(lines, line, tok[1:], f"OFFSET of {name!r}"))
        elif key == "CHANNELS" and not is_end:
            if len(tok) < 2 or not tok[1].isdigit():
                raise lines.error(line, f"CHANNELS of {name!r} must start with a channel count")
            count, names = int(tok[1]), tok[2:]
            if len(names) != count:
                raise lines.error(line, f"CHANNELS of {name!r} declares {count} channels but lists {len(names)}")
            for c in names:
                if c not in ROTATION_CHANNELS and c not in POSITION_CHANNELS:
                    valid = ", ".join([*POSITION_CHANNELS, *ROTATION_CHANNELS])
                    raise lines.error(line, f"unknown channel name {c!r} for joint {name!r} (valid: {valid})")
            out["channels"][index] = tuple(names)
        elif key == "JOINT" and not is_end:
            if len(tok) < 2:
                raise lines.error(line, "JOINT without a name")
            _parse_joint(lines, " ".join(tok[1:]), index, out, is_end=False)
        elif key == "End" and not is_end:
            _parse_joint(lines, f"{name}_end", index, out, is_end=True)
        elif key == "}":
            return
        else:
            raise lines.error(line, f"unexpected {' '.join(tok)!r} inside joint {name!r}")


def parse_bvh(text: str, path: str | Path = "<string>") -> BvhClip:
    """Parse BVH text (see the module docstring); errors name ``path`` and the line."""
    lines = _Lines(Path(path), text)
    line, tok = lines.next("HIERARCHY")
    if tok != ["HIERARCHY"]:
        # Not quoted: a file that is not BVH at all (a symlink to a system file) must not be echoed.
        raise lines.error(line, "expected HIERARCHY on the first line: not a BVH file")
    line, tok = lines.next("ROOT")
    if tok[0] != "ROOT" or len(tok) < 2:
        raise lines.error(line, f"expected ROOT <name>, found {' '.join(tok)!r}")
    out: dict = {"names": [], "parents": [], "offsets": [], "channels": []}
    _parse_joint(lines, " ".join(tok[1:]), -1, out, is_end=False)
    if lines.pos >= len(lines.items):
        raise lines.error(lines.items[-1][0], "missing MOTION section after the hierarchy")
    line, tok = lines.next("MOTION")
    if tok != ["MOTION"]:
        raise lines.error(line, f"missing MOTION section: expected MOTION after the hierarchy, "
                                f"found {' '.join(tok)!r}")
    line, tok = lines.next("Frames:")
    if len(tok) != 2 or tok[0] != "Frames:" or not tok[1].isdigit():
        raise lines.error(line, f"expected 'Frames: <count>', found {' '.join(tok)!r}")
    n_frames = int(tok[1])
    line, tok = lines.next("Frame Time:")
    if len(tok) != 3 or tok[:2] != ["Frame", "Time:"]:
        raise lines.error(line, f"expected 'Frame Time: <seconds>', found {' '.join(tok)!r}")
    frame_time = _floats(lines, line, tok[2:], "Frame Time")[0]
    if not frame_time > 0:
        raise lines.error(line, f"Frame Time must be positive, got {frame_time}")
    n_channels = sum(len(c) for c in out["channels"])
    frames = np.empty((n_frames, n_channels))
    for t in range(n_frames):
        if lines.pos >= len(lines.items):
            last = lines.items[-1][0]
            raise lines.error(last, f"truncated file: {t} frames of the declared {n_frames}")
        line, tok = lines.next("a frame")
        if len(tok) != n_channels:
            raise lines.error(line, f"frame {t} has {len(tok)} values, the hierarchy declares {n_channels} channels")
        frames[t] = _floats(lines, line, tok, f"frame {t}")
    if lines.pos < len(lines.items):
        line, _ = lines.items[lines.pos]
        raise lines.error(line, f"more frame lines than the declared {n_frames}")
    return BvhClip(names=tuple(out["names"]), parents=np.array(out["parents"], dtype=int),
                   offsets=np.array(out["offsets"], dtype=float).reshape(-1, 3),
                   channels=tuple(out["channels"]), frame_time=frame_time, frames=frames, path=Path(path))


def load_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file (any line endings). Raises :class:`BvhError` naming the file and line."""
    path = Path(path)
    return parse_bvh(read_text(path, BvhError, "BVH"), path)
