"""Acclaim ASF/AMC motion capture (CMU's own format): parsers and forward kinematics.

The ASF file holds the skeleton: ``:units`` (mass, length, angle), ``:root`` (the AMC value ``order`` of the
root, the rotation order ``axis``, a rest ``position`` and ``orientation``), ``:bonedata`` (per bone a unit
``direction`` and a ``length`` in the rest pose, in world coordinates, an ``axis`` ``a b c ORDER`` that
fixes the bone's local frame, its ``dof`` list and ``limits``) and ``:hierarchy`` (parent then children).
The AMC file holds one block per frame: the frame number, then one line per bone with its DOF values in the
order of the bone's ``dof`` list (degrees unless ``:units angle rad``).

Forward kinematics (column vectors). ``E(a, ORDER)`` is the Euler rotation that turns about the first axis
of ``ORDER`` first, so ``E((a, b, c), "XYZ") = Rz(c) Ry(b) Rx(a)``. Per bone ``b`` with parent ``p``:

    C_b = E(axis_b),  M_b = product of the DOF rotations, first listed DOF applied first,
    W_b = W_p C_b M_b C_b^-1,   end_b = start_b + W_b (length_b direction_b),   start_b = end_p

and for the root ``W_r = C_r M_r C_r^-1`` with ``C_r = E(orientation, axis)``, ``M_r`` from the AMC
rotation values in the ``axis`` order, and its position the rest ``position`` plus the AMC translation.
Positions come out in ASF length units; ``AsfSkeleton.unit_m`` converts them to metres under CMU's
convention that ``:units length L`` means one unit is 1/L inch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.errors import HarnessError
from harness.io import read_text
from harness.motion.bvh import axis_rotation

ROTATION_DOFS = {"rx": 0, "ry": 1, "rz": 2}
#: DOF names the ASF specification defines; translations and bone stretch are valid but not supported.
KNOWN_DOFS = ("rx", "ry", "rz", "tx", "ty", "tz", "l")
INCH_M = 0.0254


class AsfAmcError(HarnessError):
    """An ASF or AMC file that cannot be read; the message names the file, the line and the problem."""


def euler_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """``E(angles, order)``: rotations ``(..., 3, 3)`` turning about ``order[0]`` first (radians ``(..., 3)``,
    one angle per letter of ``order`` in that order)."""
    angles = np.asarray(angles, dtype=float)
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for k, letter in enumerate(order.upper()):
        out = axis_rotation("XYZ".index(letter), angles[..., k]) @ out
    return out


@dataclass(frozen=True)
class AsfSkeleton:
    """A parsed ASF skeleton. Index 0 is the root; bones follow in file order.

    names ``(B,)``, parents ``(B,)`` (-1 for the root), directions ``(B, 3)`` unit, lengths ``(B,)`` in ASF
    units, axes ``(B, 3, 3)`` the matrices ``C``, dofs per bone (lowercase names), limits per bone
    ``(n_dof, 2)`` in the file's angle unit. root_order: the AMC root value names (``TX`` ... ``RZ``).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    directions: np.ndarray
    lengths: np.ndarray
    axes: np.ndarray
    dofs: tuple[tuple[str, ...], ...]
    limits: tuple[np.ndarray, ...]
    root_order: tuple[str, ...]
    root_axis: str
    root_position: np.ndarray
    length_unit: float = 1.0
    mass_unit: float = 1.0
    angle_unit: str = "deg"
    path: Path | None = None

    @property
    def unit_m(self) -> float:
        """Metres per ASF length unit (CMU: ``:units length L`` means 1/L inch)."""
        return INCH_M / self.length_unit

    def index(self, name: str) -> int:
        return self.names.index(name)

    @property
    def leaves(self) -> tuple[int, ...]:
        """Indices of the bones without children (their ends are extra points of the forward kinematics)."""
        parents = set(self.parents.tolist())
        return tuple(i for i in range(1, len(self.names)) if i not in parents)


@dataclass(frozen=True)
class AmcMotion:
    """AMC frames: ``values[bone]`` is ``(T, n_dof)`` in the file's angle unit (root: ``(T, len(order))``).

    frame_numbers ``(T,)`` as written in the file; lines ``(T,)`` the line of each frame number.
    """

    values: dict[str, np.ndarray]
    frame_numbers: np.ndarray
    path: Path | None = None
    lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def n_frames(self) -> int:
        return len(self.frame_numbers)


def _read_lines(path: Path, kind: str) -> list[tuple[int, list[str]]]:
    text = read_text(path, AsfAmcError, kind)
    return [(i + 1, line.split()) for i, line in enumerate(text.splitlines())
            if line.strip() and not line.lstrip().startswith("#")]


def _floats(path: Path, line: int, tokens: list[str], what: str) -> np.ndarray:
    try:
        return np.array([float(t) for t in tokens])
    except ValueError:
        raise AsfAmcError(f"{path}:{line}: non-numeric value in {what}: {' '.join(tokens)!r}") from None


def _parse_limits(path: Path, line: int, tokens: list[str]) -> list[float]:
    text = " ".join(tokens).replace("(", " ").replace(")", " ")
    return list(_floats(path, line, text.split(), "limits"))


def load_asf(path: str | Path) -> AsfSkeleton:
    """Read an ASF skeleton. Errors name the file and line (unknown DOF names, malformed values, ...)."""
    path = Path(path)
    items = _read_lines(path, "ASF")
    units = {"mass": 1.0, "length": 1.0, "angle": "deg"}
    root = {"order": ("TX", "TY", "TZ", "RX", "RY", "RZ"), "axis": "XYZ", "position": np.zeros(3),
            "orientation": np.zeros(3)}
    bones: list[dict] = []
    hierarchy: list[tuple[int, list[str]]] = []
    section, bone, in_limits = None, None, False
    for line, tok in items:
        key = tok[0]
        if key.startswith(":"):
            section, in_limits = key[1:], False
            continue
        if section == "units":
            if key in ("mass", "length"):
                units[key] = float(_floats(path, line, tok[1:2], f"units {key}")[0])
            elif key == "angle":
                if tok[1:2] not in (["deg"], ["rad"]):
                    raise AsfAmcError(f"{path}:{line}: units angle must be deg or rad, got {' '.join(tok[1:])!r}")
                units["angle"] = tok[1]
        elif section == "root":
            if key == "order":
                root["order"] = tuple(t.upper() for t in tok[1:])
            elif key == "axis":
                root["axis"] = tok[1].upper()
            elif key in ("position", "orientation"):
                root[key] = _floats(path, line, tok[1:4], f"root {key}")
        elif section == "bonedata":
            if key == "begin":
                bone, in_limits = {"line": line, "dof": (), "limits": [], "axis": (np.zeros(3), "XYZ")}, False
            elif key == "end":
                if bone is None or "name" not in bone:
                    raise AsfAmcError(f"{path}:{line}: bone block without a name")
                bones.append(bone)
                bone = None
            elif bone is None:
                raise AsfAmcError(f"{path}:{line}: {key!r} outside a begin/end bone block")
            elif key == "name":
                bone["name"], in_limits = tok[1], False
            elif key == "id":
                in_limits = False
            elif key == "direction":
                bone["direction"] = _floats(path, line, tok[1:4], f"direction of {bone.get('name')!r}")
            elif key == "length":
                bone["length"] = float(_floats(path, line, tok[1:2], f"length of {bone.get('name')!r}")[0])
            elif key == "axis":
                if len(tok) != 5:
                    raise AsfAmcError(f"{path}:{line}: axis needs three angles and an order, got {' '.join(tok[1:])!r}")
                bone["axis"] = (_floats(path, line, tok[1:4], "axis"), tok[4].upper())
            elif key == "dof":
                names = tuple(t.lower() for t in tok[1:])
                for d in names:
                    if d not in KNOWN_DOFS:
                        raise AsfAmcError(f"{path}:{line}: unknown DOF name {d!r} in bone {bone.get('name')!r} "
                                          f"(valid: {', '.join(KNOWN_DOFS)})")
                    if d not in ROTATION_DOFS:
                        raise AsfAmcError(f"{path}:{line}: DOF {d!r} of bone {bone.get('name')!r} is not supported "
                                          f"(only rotations rx, ry, rz)")
                bone["dof"] = names
            elif key == "limits" or (in_limits and key.startswith("(")):
                bone["limits"].append(_parse_limits(path, line, tok[1:] if key == "limits" else tok))
                in_limits = True
            else:
                raise AsfAmcError(f"{path}:{line}: unexpected {key!r} in bone {bone.get('name')!r}")
        elif section == "hierarchy":
            if key not in ("begin", "end"):
                hierarchy.append((line, tok))
    if not bones:
        raise AsfAmcError(f"{path}: no :bonedata bones found")
    for b in bones:
        for need in ("direction", "length"):
            if need not in b:
                raise AsfAmcError(f"{path}:{b['line']}: bone {b['name']!r} has no {need}")
    names = ("root",) + tuple(b["name"] for b in bones)
    parents = np.full(len(names), -1, dtype=int)
    for line, tok in hierarchy:
        if tok[0] not in names:
            raise AsfAmcError(f"{path}:{line}: hierarchy names unknown bone {tok[0]!r}")
        for child in tok[1:]:
            if child not in names:
                raise AsfAmcError(f"{path}:{line}: hierarchy names unknown bone {child!r}")
            parents[names.index(child)] = names.index(tok[0])
    orphans = [n for n, p in zip(names[1:], parents[1:]) if p < 0]
    if orphans:
        raise AsfAmcError(f"{path}: bones without a parent in :hierarchy: {', '.join(orphans)}")
    to_rad = np.pi / 180.0 if units["angle"] == "deg" else 1.0
    axes = [euler_matrix(root["orientation"] * to_rad, root["axis"])]
    axes += [euler_matrix(b["axis"][0] * to_rad, b["axis"][1]) for b in bones]
    directions = np.array([np.zeros(3)] + [b["direction"] / np.linalg.norm(b["direction"]) for b in bones])
    return AsfSkeleton(
        names=names, parents=parents, directions=directions,
        lengths=np.array([0.0] + [b["length"] for b in bones]), axes=np.array(axes),
        dofs=(tuple(d.lower() for d in root["order"] if d.startswith("R")),) + tuple(b["dof"] for b in bones),
        limits=(np.zeros((0, 2)),) + tuple(np.array(b["limits"], dtype=float).reshape(-1, 2) for b in bones),
        root_order=root["order"], root_axis=root["axis"], root_position=root["position"],
        length_unit=units["length"], mass_unit=units["mass"], angle_unit=units["angle"], path=path)


def load_amc(path: str | Path, skeleton: AsfSkeleton) -> AmcMotion:
    """Read an AMC file against its skeleton. Errors name the file and line: a frame missing bones (a
    truncated file), unknown bones, wrong value counts, non-numeric values."""
    path = Path(path)
    items = _read_lines(path, "AMC")
    expected = {"root": len(skeleton.root_order)}
    expected.update({n: len(d) for n, d in zip(skeleton.names[1:], skeleton.dofs[1:]) if d})
    rows: dict[str, list[np.ndarray]] = {n: [] for n in expected}
    numbers: list[int] = []
    frame_lines: list[int] = []
    seen: set[str] = set()

    def close_frame() -> None:
        missing = [n for n in expected if n not in seen]
        if missing:
            where = frame_lines[-1]
            raise AsfAmcError(f"{path}:{where}: frame {numbers[-1]} is missing bones {', '.join(missing)} "
                              f"(truncated file?)")

    for line, tok in items:
        if tok[0].startswith(":"):
            continue
        if len(tok) == 1 and tok[0].isdigit():
            if numbers:
                close_frame()
            numbers.append(int(tok[0]))
            frame_lines.append(line)
            seen = set()
            continue
        if not numbers:
            raise AsfAmcError(f"{path}:{line}: bone values before the first frame number")
        name = tok[0]
        if name not in expected:
            known = name in skeleton.names
            problem = "has no DOFs in the ASF" if known else "is not a bone of the ASF"
            raise AsfAmcError(f"{path}:{line}: {name!r} {problem} ({skeleton.path})")
        if len(tok) - 1 != expected[name]:
            raise AsfAmcError(f"{path}:{line}: bone {name!r} needs {expected[name]} values, found {len(tok) - 1}")
        if name in seen:
            raise AsfAmcError(f"{path}:{line}: bone {name!r} given twice in frame {numbers[-1]}")
        seen.add(name)
        rows[name].append(_floats(path, line, tok[1:], f"bone {name!r}"))
    if not numbers:
        raise AsfAmcError(f"{path}: no frames")
    close_frame()
    values = {n: np.array(v).reshape(len(numbers), expected[n]) for n, v in rows.items()}
    return AmcMotion(values=values, frame_numbers=np.array(numbers), path=path, lines=np.array(frame_lines))


def joint_names(skeleton: AsfSkeleton) -> tuple[str, ...]:
    """Names of the points :func:`asf_forward_kinematics` returns: the root, each bone's start (named by the
    bone) and each leaf bone's end (``<bone>_end``)."""
    return skeleton.names + tuple(f"{skeleton.names[i]}_end" for i in skeleton.leaves)


def asf_forward_kinematics(skeleton: AsfSkeleton, motion: AmcMotion, start: int = 0,
                           stop: int | None = None) -> np.ndarray:
    """World positions ``(T, J, 3)`` in ASF length units of the points named by :func:`joint_names`,
    for AMC frames ``[start, stop)``."""
    to_rad = np.pi / 180.0 if skeleton.angle_unit == "deg" else 1.0
    root_vals = motion.values["root"][start:stop]
    n = len(root_vals)
    order = skeleton.root_order
    trans = np.zeros((n, 3))
    rot = np.zeros((n, 3))
    for k, name in enumerate(order):
        if name.startswith("T"):
            trans[:, "XYZ".index(name[1])] = root_vals[:, k]
        else:
            rot[:, "XYZ".index(name[1])] = root_vals[:, k] * to_rad
    m_root = euler_matrix(rot[:, ["XYZ".index(a) for a in skeleton.root_axis]], skeleton.root_axis)
    c = skeleton.axes
    c_inv = np.transpose(c, (0, 2, 1))
    world = np.empty((len(skeleton.names), n, 3, 3))
    start_pos = np.empty((len(skeleton.names), n, 3))
    end_pos = np.empty((len(skeleton.names), n, 3))
    world[0] = c[0] @ m_root @ c_inv[0]
    start_pos[0] = end_pos[0] = skeleton.root_position + trans
    for b in range(1, len(skeleton.names)):
        p = skeleton.parents[b]
        m = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        if skeleton.dofs[b]:
            vals = motion.values[skeleton.names[b]][start:stop] * to_rad
            for k, d in enumerate(skeleton.dofs[b]):
                m = axis_rotation(ROTATION_DOFS[d], vals[:, k]) @ m
        world[b] = world[p] @ c[b] @ m @ c_inv[b]
        start_pos[b] = end_pos[p]
        end_pos[b] = start_pos[b] + world[b] @ (skeleton.lengths[b] * skeleton.directions[b])
    points = np.concatenate([start_pos, end_pos[list(skeleton.leaves)]], axis=0)
    return np.transpose(points, (1, 0, 2))
