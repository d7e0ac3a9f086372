"""BVH parser and forward kinematics against hand-computed positions, and its error messages."""

import numpy as np
import pytest

from harness.errors import HarnessError
from harness.motion.bvh import BvhError, load_bvh, parse_bvh

# Root with 6 channels; J1 one unit up (y) with Z then X rotation; an end site one unit along z.
TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT J1
  {
    OFFSET 0 1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 1
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
1 2 3 90 0 0 0 90 0
0 0 0 0 0 0 90 90 0
"""


def _write(tmp_path, text, name="t.bvh", newline="\n"):
    path = tmp_path / name
    path.write_bytes(text.replace("\n", newline).encode())
    return path


def test_structure_is_as_declared(tmp_path):
    clip = load_bvh(_write(tmp_path, TINY))
    assert clip.names == ("Hips", "J1", "J1_end")
    np.testing.assert_array_equal(clip.parents, [-1, 0, 1])
    assert clip.channels[1] == ("Zrotation", "Xrotation", "Yrotation")
    np.testing.assert_allclose(clip.offsets, [[0, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert clip.frames.shape == (2, 9)
    assert clip.fps == pytest.approx(120.0, rel=1e-4)


def test_forward_kinematics_matches_hand_computation(tmp_path):
    pos = load_bvh(_write(tmp_path, TINY)).positions()
    # Frame 0: root at (1, 2, 3) turned 90 deg about z (x -> y, y -> -x); J1 = root + Rz (0, 1, 0) =
    # (0, 2, 3); J1 turns 90 deg about x, so the end site = J1 + Rz Rx (0, 0, 1) = J1 + Rz (0, -1, 0) = (1, 2, 3).
    np.testing.assert_allclose(pos[0], [[1, 2, 3], [0, 2, 3], [1, 2, 3]], atol=1e-12)
    # Frame 1: J1 = (0, 1, 0), Zrotation then Xrotation as declared: Rz Rx (0, 0, 1) = Rz (0, -1, 0) = (1, 0, 0).
    # (The other order, Rx Rz, would give (0, -1, 0).)
    np.testing.assert_allclose(pos[1], [[0, 0, 0], [0, 1, 0], [1, 1, 0]], atol=1e-12)


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_line_endings_do_not_matter(tmp_path, newline):
    a = load_bvh(_write(tmp_path, TINY))
    b = load_bvh(_write(tmp_path, TINY, "crlf.bvh", newline))
    np.testing.assert_array_equal(a.frames, b.frames)
    mixed = TINY.replace("\n", "\r\n", 5)
    np.testing.assert_array_equal(load_bvh(_write(tmp_path, mixed, "mixed.bvh")).frames, a.frames)


@pytest.mark.parametrize("edit, line, words", [
    (lambda t: t[:t.index("MOTION")], 15, "missing MOTION"),
    (lambda t: t.replace("0 0 0 0 0 0 90 90 0", "0 0 0 0 0 0 90 90"), 20, "8 values"),
    (lambda t: t.replace("1 2 3 90", "1 2 x 90"), 19, "non-numeric value 'x'"),
    (lambda t: t.replace("Zrotation Xrotation Yrotation", "Zrotation Wrotation Yrotation"), 9,
     "unknown channel name 'Wrotation'"),
    (lambda t: t.replace("0 0 0 0 0 0 90 90 0\n", ""), 19, "truncated file: 1 frames of the declared 2"),
    (lambda t: t[:t.index("    End Site")], 9, "truncated file"),
])
def test_errors_name_file_line_and_problem(tmp_path, edit, line, words):
    path = _write(tmp_path, edit(TINY), "bad.bvh")
    with pytest.raises(BvhError) as exc:
        load_bvh(path)
    assert isinstance(exc.value, HarnessError)
    assert str(exc.value).startswith(f"{path}:{line}:")
    assert words in str(exc.value)


def test_missing_file_is_reported(tmp_path):
    with pytest.raises(BvhError, match="no such BVH file"):
        load_bvh(tmp_path / "absent.bvh")


def test_string_parser_agrees_with_file_parser(tmp_path):
    np.testing.assert_array_equal(parse_bvh(TINY).positions(), load_bvh(_write(tmp_path, TINY)).positions())
