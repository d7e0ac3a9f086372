"""Which source joint drives which humanoid56 body: the alias table, user mapping files, and their resolution.

A correspondence pairs a source joint (a point the source's forward kinematics returns) with a humanoid56
*target*: a body, whose *origin* (its joint centre) should follow the joint, or a *site*, a named point
fixed on a body (:data:`SITES`). Sites let a source's end sites drive joints whose child has no joint
centre of its own: the toe tips drive the toe joints, which no joint centre can. The three CMU skeletons name the same bones
differently, and the two BVH conversions even reuse names for different bones (``LeftShoulder`` is the
clavicle in the MotionBuilder conversion and the upper arm in the 3dsMax one), so the table has one
column per source dialect; the dialect of a clip is the one whose column accounts for all its joints.

Source joints that sit on top of another mapped joint (a zero BVH offset, or an ASF bone that starts
where its sibling starts), fingers, thumbs and end sites (``<joint>_end``) are ignored explicitly: each
dialect lists them, so that a joint nobody thought about is reported instead of silently dropped.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from harness.errors import HarnessError

DIALECTS = ("asf", "bvh-motionbuilder", "bvh-3dsmax")
MAX_MAPPING_BYTES = 1 << 20     # a joint-mapping file
MAPPING_SUFFIXES = (".yaml", ".yml", ".csv")

#: humanoid56 body or site -> source joint name per dialect (None: the dialect has no joint for it).
ALIASES: dict[str, tuple[str | None, str | None, str | None]] = {
    #  body          CMU ASF       BVH MotionBuilder  BVH 3dsMax
    "pelvis":      ("root",       "Hips",            "Hips"),
    "upperback":   ("upperback",  "Spine",           "Chest"),
    "thorax":      ("thorax",     "Spine1",          "Chest2"),
    "lowerneck":   ("lowerneck",  None,              None),
    "upperneck":   ("upperneck",  "Neck1",           "Neck"),
    "head":        ("head",       "Head",            "Head"),
    "lhumerus":    ("lhumerus",   "LeftArm",         "LeftShoulder"),
    "lradius":     ("lradius",    "LeftForeArm",     "LeftElbow"),
    "lwrist":      ("lwrist",     "LeftHand",        "LeftWrist"),
    "lhand":       ("lhand",      None,              None),
    "rhumerus":    ("rhumerus",   "RightArm",        "RightShoulder"),
    "rradius":     ("rradius",    "RightForeArm",    "RightElbow"),
    "rwrist":      ("rwrist",     "RightHand",       "RightWrist"),
    "rhand":       ("rhand",      None,              None),
    "lfemur":      ("lfemur",     "LeftUpLeg",       "LeftHip"),
    "ltibia":      ("ltibia",     "LeftLeg",         "LeftKnee"),
    "lfoot":       ("lfoot",      "LeftFoot",        "LeftAnkle"),
    "ltoes":       ("ltoes",      "LeftToeBase",     "LeftToe"),
    "rfemur":      ("rfemur",     "RightUpLeg",      "RightHip"),
    "rtibia":      ("rtibia",     "RightLeg",        "RightKnee"),
    "rfoot":       ("rfoot",      "RightFoot",       "RightAnkle"),
    "rtoes":       ("rtoes",      "RightToeBase",    "RightToe"),
    "ltoes_tip":   ("ltoes_end",  "LeftToeBase_end", "LeftToe_end"),
    "rtoes_tip":   ("rtoes_end",  "RightToeBase_end", "RightToe_end"),
    # The BVH conversions hang their hands off the end of ASF's radius (humanoid56's lwrist origin),
    # 9 cm before the real wrist, so their finger and thumb directions do not match the humanoid's hand
    # (tried: hand residuals of 2-8 cm and worse arms); their hands stay at the warm start.
    "lknuckles":   ("lfingers",   None,              None),
    "rknuckles":   ("rfingers",   None,              None),
    "lthumb_tip":  ("lthumb_end", None,              None),
    "rthumb_tip":  ("rthumb_end", None,              None),
}

#: Source joints each dialect ignores on purpose (besides end sites, ``<joint>_end``), with the reason.
IGNORED: dict[str, dict[str, str]] = {
    "asf": {
        **{n: "starts at the root" for n in ("lhipjoint", "rhipjoint", "lowerback")},
        **{n: "starts where lowerneck starts" for n in ("lclavicle", "rclavicle")},
        **{n: "starts where the hand starts (its end drives the thumb tip)" for n in ("lthumb", "rthumb")},
    },
    "bvh-motionbuilder": {
        **{n: "zero offset from Hips" for n in ("LHipJoint", "RHipJoint", "LowerBack")},
        **{n: "zero offset from Spine1" for n in ("Neck", "LeftShoulder", "RightShoulder")},
        **{n: "zero offset from the hand" for n in ("LeftFingerBase", "RightFingerBase")},
        **{n: "finger or thumb (see the hand sites above)" for n in ("LeftHandIndex1", "RightHandIndex1", "LThumb",
                                                                       "RThumb")},
    },
    "bvh-3dsmax": {
        **{n: "zero offset from Hips" for n in ("LHipJoint", "RHipJoint", "lowerback")},
        **{n: "zero offset from Chest2" for n in ("lowerneck", "LeftCollar", "RightCollar")},
        **{n: "zero offset from the wrist" for n in ("lhand", "rhand")},
        **{n: "finger or thumb (see the hand sites above)" for n in ("LFingers", "RFingers", "LThumb", "RThumb")},
    },
}

END_SITE_SUFFIX = "_end"

#: humanoid56 sites: name -> (body, point in the body frame, metres). Points sit where the source's end
#: site or bone start sits on a real body: the toe tip at the front of the toes box, halfway up it (its
#: direction from the toes' joint is horizontal in the zero pose, like the source toe bones at rest).
SITES: dict[str, tuple[str, tuple[float, float, float]]] = {
    "ltoes_tip": ("ltoes", (0.08, 0.0, 0.0)),
    "rtoes_tip": ("rtoes", (0.08, 0.0, 0.0)),
    # On the hand's axis at the knuckles: its direction from the wrist drives hand flexion and deviation.
    "lknuckles": ("lhand", (0.0, 0.0, -0.1)),
    "rknuckles": ("rhand", (0.0, 0.0, -0.1)),
    # The thumb tip, 45 degrees between the hand's axis and forward (palms face the thighs at the zero
    # pose, like CMU's rest thumbs): the one hand point off the forearm's axis, so it drives the twist.
    "lthumb_tip": ("lhand", (0.03, 0.0, -0.03)),
    "rthumb_tip": ("rhand", (0.03, 0.0, -0.03)),
}


class SkeletonMappingError(HarnessError):
    """Source joints that no table or mapping file accounts for, or a malformed mapping file."""


def target_names(body_names: tuple[str, ...]) -> tuple[str, ...]:
    """Every name a source joint may drive: the humanoid's bodies, then :data:`SITES`."""
    return tuple(body_names) + tuple(SITES)


def dialect_table(dialect: str) -> dict[str, str | None]:
    """Source joint name -> humanoid56 body or site (None: ignored) for one dialect of :data:`ALIASES`."""
    if dialect not in DIALECTS:
        raise SkeletonMappingError(f"unknown skeleton dialect {dialect!r}; dialects: {', '.join(DIALECTS)}")
    col = DIALECTS.index(dialect)
    table: dict[str, str | None] = {names[col]: body for body, names in ALIASES.items() if names[col]}
    table.update({name: None for name in IGNORED[dialect]})
    return table


def _apply(table: dict[str, str | None], joints: tuple[str, ...]) -> tuple[dict[str, str], list[str]]:
    mapping, unmapped = {}, []
    for name in joints:
        if name in table:
            if table[name] is not None:
                mapping[name] = table[name]
        elif not name.endswith(END_SITE_SUFFIX):
            unmapped.append(name)
    return mapping, unmapped


def detect_dialect(joints: tuple[str, ...] | list[str]) -> str | None:
    """The dialect whose table accounts for every joint, or None."""
    for dialect in DIALECTS:
        if not _apply(dialect_table(dialect), tuple(joints))[1]:
            return dialect
    return None


def resolve_correspondence(joints: tuple[str, ...] | list[str], mapping: dict[str, str | None] | None = None,
                           body_names: tuple[str, ...] | None = None, where: str = "source skeleton"
                           ) -> dict[str, str]:
    """Source joint -> humanoid56 body or site for the joints of one clip.

    With ``mapping`` (from :func:`load_mapping`), that mapping is used alone; otherwise the dialect whose
    table accounts for every joint. Raises :class:`SkeletonMappingError` listing the unmapped joints.
    ``body_names`` (the humanoid's bodies) are checked when given (site names are always valid).
    """
    joints = tuple(joints)
    if mapping is not None:
        result, unmapped = _apply(mapping, joints)
        if unmapped:
            raise SkeletonMappingError(f"{where}: joints not in the mapping file: {', '.join(unmapped)}")
    else:
        candidates = [(len(_apply(dialect_table(d), joints)[1]), d) for d in DIALECTS]
        n_missing, best = min(candidates)
        result, unmapped = _apply(dialect_table(best), joints)
        if unmapped:
            raise SkeletonMappingError(
                f"{where}: no joint-name table fits; closest is {best!r}, which does not map "
                f"{', '.join(unmapped)} (give a mapping file: source joint -> humanoid56 body)")
    if body_names is not None:
        bad = sorted({b for b in result.values() if b not in target_names(body_names)})
        if bad:
            raise SkeletonMappingError(f"{where}: unknown humanoid56 bodies or sites {', '.join(bad)}")
    return result


def load_mapping(path: str | Path, body_names: tuple[str, ...] | None = None) -> dict[str, str | None]:
    """Read a user mapping file: source joint -> humanoid56 body or site, ``~``/empty to ignore a joint.

    ``.yaml``/``.yml``: a mapping ``{joint: body}``. ``.csv``: rows ``joint,body`` (a header row
    ``source,body`` is allowed). Errors name the file and the key or line.
    """
    path = Path(path)
    if not path.is_file():
        raise SkeletonMappingError(f"{path}: no such mapping file")
    out: dict[str, str | None] = {}
    if path.suffix.lower() in MAPPING_SUFFIXES[:2]:
        from harness import safe_yaml

        data = safe_yaml.load(path, SkeletonMappingError, "mapping", MAX_MAPPING_BYTES)
        if not isinstance(data, dict):
            raise SkeletonMappingError(f"{path}: expected a mapping 'source joint: humanoid56 body'")
        for key, value in data.items():
            if value is not None and not isinstance(value, str):
                raise SkeletonMappingError(f"{path}: key {key!r}: body must be a name or ~, got {value!r}")
            out[str(key)] = value or None
    elif path.suffix.lower() == ".csv":
        from harness.io import read_text

        text = read_text(path, SkeletonMappingError, "mapping", MAX_MAPPING_BYTES)
        for lineno, row in enumerate(csv.reader(io.StringIO(text, newline="")), start=1):
            if not row or row[0].startswith("#"):
                continue
            if lineno == 1 and [c.strip().lower() for c in row[:2]] == ["source", "body"]:
                continue
            if len(row) > 2:
                raise SkeletonMappingError(f"{path}:{lineno}: expected 'joint,body', got {len(row)} columns")
            out[row[0].strip()] = (row[1].strip() if len(row) > 1 else "") or None
    else:
        raise SkeletonMappingError(f"{path}: mapping files must be .yaml, .yml or .csv")
    if body_names is not None:
        for key, value in out.items():
            if value is not None and value not in target_names(body_names):
                raise SkeletonMappingError(f"{path}: key {key!r}: unknown humanoid56 body or site {value!r}")
    return out
