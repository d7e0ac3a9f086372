"""ASF/AMC parsing and forward kinematics against hand-computed positions, and the error messages."""

import numpy as np
import pytest

from harness.errors import HarnessError
from harness.motion.asf_amc import AsfAmcError, asf_forward_kinematics, joint_names, load_amc, load_asf

# Bone a: 2 units up, DOFs rx rz. Bone b (child of a): 1 unit along x, its axis turned 90 deg about z, DOF rx.
ASF = """# tiny skeleton
:version 1.10
:name tiny
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction 0 1 0
     length 2
     axis 0 0 0 XYZ
    dof rx rz
    limits (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
     id 2
     name b
     direction 1 0 0
     length 1
     axis 0 0 90 XYZ
    dof rx
    limits (-180.0 180.0)
  end
:hierarchy
  begin
    root a
    a b
  end
"""

AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 0 0 0 0 0 0
a 90 0
b 90
2
root 1 0 0 0 90 0
a 0 0
b 0
3
root 0 0 0 0 0 0
a 90 90
b 0
"""


@pytest.fixture
def files(tmp_path):
    asf, amc = tmp_path / "t.asf", tmp_path / "t.amc"
    asf.write_bytes(ASF.replace("\n", "\r\n").encode())
    amc.write_text(AMC)
    return asf, amc


def test_skeleton_fields(files):
    skel = load_asf(files[0])
    assert skel.names == ("root", "a", "b")
    np.testing.assert_array_equal(skel.parents, [-1, 0, 1])
    assert skel.dofs[1:] == (("rx", "rz"), ("rx",))
    assert skel.limits[1].shape == (2, 2)
    assert skel.unit_m == pytest.approx(0.0254 / 0.45)
    assert joint_names(skel) == ("root", "a", "b", "b_end")


def test_forward_kinematics_matches_hand_computation(files):
    skel = load_asf(files[0])
    pos = asf_forward_kinematics(skel, load_amc(files[1], skel))
    # Frame 1: W_a = Rx(90): a ends at Rx(90) (0, 2, 0) = (0, 0, 2). b: C = Rz(90), M = Rx(90), so
    # C M C^-1 = Ry(90) (a turn about C x = y); W_b = Rx(90) Ry(90); b_end = (0, 0, 2) + Rx(90) (0, 0, -1) = (0, 1, 2).
    np.testing.assert_allclose(pos[0], [[0, 0, 0], [0, 0, 0], [0, 0, 2], [0, 1, 2]], atol=1e-12)
    # Frame 2: root moved to (1, 0, 0) and turned 90 deg about y: (0, 2, 0) stays, (1, 0, 0) -> (0, 0, -1).
    np.testing.assert_allclose(pos[1], [[1, 0, 0], [1, 0, 0], [1, 2, 0], [1, 2, -1]], atol=1e-12)
    # Frame 3: dof order rx then rz: W_a = Rz(90) Rx(90); b_end = (0, 0, 2) + Rz Rx (1, 0, 0) = (0, 1, 2)
    # (the other order, Rx Rz, would put it at (0, 0, 3)).
    np.testing.assert_allclose(pos[2], [[0, 0, 0], [0, 0, 0], [0, 0, 2], [0, 1, 2]], atol=1e-12)


def test_truncated_amc_names_file_line_and_missing_bone(files, tmp_path):
    skel = load_asf(files[0])
    bad = tmp_path / "cut.amc"
    bad.write_text(AMC[:AMC.rindex("b 0")])
    with pytest.raises(AsfAmcError) as exc:
        load_amc(bad, skel)
    assert isinstance(exc.value, HarnessError)
    assert str(exc.value).startswith(f"{bad}:11:")
    assert "frame 3 is missing bones b" in str(exc.value)


def test_unknown_dof_names_file_and_line(files, tmp_path):
    bad = tmp_path / "bad.asf"
    bad.write_text(ASF.replace("dof rx\n", "dof rq\n"))
    with pytest.raises(AsfAmcError) as exc:
        load_asf(bad)
    assert str(exc.value).startswith(f"{bad}:30:")
    assert "unknown DOF name 'rq'" in str(exc.value)


def test_amc_value_errors(files, tmp_path):
    skel = load_asf(files[0])
    for text, words in [(AMC.replace("a 90 0", "a 90"), "needs 2 values, found 1"),
                        (AMC.replace("b 90", "b nine"), "non-numeric"),
                        (AMC.replace("b 90", "c 90"), "'c' is not a bone")]:
        bad = tmp_path / "bad.amc"
        bad.write_text(text)
        with pytest.raises(AsfAmcError, match=words):
            load_amc(bad, skel)


def test_real_skeleton_parses(request):
    from tests.conftest import require_mocap

    directory = require_mocap()
    skel = load_asf(directory / "02.asf")
    assert len(skel.names) == 31 and skel.dofs[skel.index("lfemur")] == ("rx", "ry", "rz")
