"""Joint-name conventions of BVH files and their mapping onto the canonical gltrack joints.

Three conventions are known (matching is case-insensitive and ignores namespace prefixes such
as ``mixamorig:``):

* ``"motionbuilder"`` (CMU / Hahne MotionBuilder-friendly, also Mixamo-like): ``Hips``,
  ``LowerBack``, ``Spine``, ``Spine1``, ``Neck``, ``Neck1``, ``Head``, ``LeftShoulder``
  (**clavicle**), ``LeftArm`` (upper arm), ``LeftForeArm``, ``LeftHand``, ``LHipJoint``,
  ``LeftUpLeg``, ``LeftLeg``, ``LeftFoot``, ``LeftToeBase``.
* ``"3dsmax"`` (CMU / Hahne 3ds Max-friendly): ``Hips``, ``lowerback``, ``Chest``, ``Chest2``,
  ``lowerneck``, ``Neck``, ``Head``, ``LeftCollar`` (clavicle), ``LeftShoulder`` (**upper
  arm**), ``LeftElbow``, ``LeftWrist``, ``LeftHip``, ``LeftKnee``, ``LeftAnkle``, ``LeftToe``.
* ``"gltrack"``: the canonical names themselves (``pelvis``, ``l_shoulder``, ...), as written by
  :mod:`gltrack.export.bvh`, so results' ``poses.bvh`` reads back.
* ``"daz"`` (Daz/Poser): ``hip``, ``abdomen``, ``chest``, ``neck``, ``head``, ``lCollar``,
  ``lShldr``, ``lForeArm``, ``lHand``, ``lButtock``, ``lThigh``, ``lShin``, ``lFoot``.

Where the canonical skeleton has fewer joints than the file, the mapping picks the BVH joints
whose *positions* best match the canonical joint semantics and whose bones can carry the
canonical bones exactly (zero-length BVH joints are preferred as branch points); the others
are collapsed by :mod:`gltrack.motion.retarget`.
"""
from __future__ import annotations

import logging

from gltrack.body.skeleton import JOINT_NAMES

log = logging.getLogger(__name__)


def _sided(table: dict) -> dict:
    """Expand ``{"l_x": [...{L}...]}`` templates into left and right entries."""
    out = {}
    for canon, cands in table.items():
        if canon.startswith("l_"):
            for side, (L, l, lw) in (("l", ("Left", "l", "left")), ("r", ("Right", "r", "right"))):
                out[f"{side}_{canon[2:]}"] = [c.format(L=L, l=l, lw=lw) for c in cands]
        else:
            out[canon] = list(cands)
    return out


#: Candidate BVH names per canonical joint for each convention (first present one wins).
CONVENTIONS = {
    # gltrack's own names (what gltrack.export.bvh writes into results' poses.bvh).
    "gltrack": {name: [name] for name in JOINT_NAMES},
    "motionbuilder": _sided({
        "pelvis": ["Hips"],
        # LowerBack sits at the hips with the first spine rotation; Spine carries the second.
        "spine_lower": ["LowerBack", "Spine"],
        "spine_upper": ["Spine", "Spine1", "Spine2"],
        # Neck is the zero-length branch point at the top of Spine1 (base of the neck).
        "neck": ["Neck"],
        "head": ["Head"],
        "l_clavicle": ["{L}Shoulder"],
        "l_shoulder": ["{L}Arm"],
        "l_elbow": ["{L}ForeArm"],
        "l_wrist": ["{L}Hand"],
        "l_hip": ["{L}UpLeg"],
        "l_knee": ["{L}Leg"],
        "l_ankle": ["{L}Foot"],
    }),
    "3dsmax": _sided({
        "pelvis": ["Hips", "Hip", "Pelvis"],
        "spine_lower": ["lowerback", "Abdomen", "Chest"],
        "spine_upper": ["Chest", "Chest2"],
        "neck": ["lowerneck", "Neck"],
        "head": ["Head"],
        "l_clavicle": ["{L}Collar"],
        "l_shoulder": ["{L}Shoulder"],
        "l_elbow": ["{L}Elbow"],
        "l_wrist": ["{L}Wrist"],
        "l_hip": ["{L}Hip"],
        "l_knee": ["{L}Knee"],
        "l_ankle": ["{L}Ankle"],
    }),
    "daz": _sided({
        "pelvis": ["hip"],
        "spine_lower": ["abdomen", "abdomenLower", "abdomen1"],
        "spine_upper": ["chest", "chestLower", "abdomenUpper", "abdomen2"],
        "neck": ["neck", "neckLower"],
        "head": ["head"],
        "l_clavicle": ["{l}Collar"],
        "l_shoulder": ["{l}Shldr", "{l}ShldrBend"],
        "l_elbow": ["{l}ForeArm", "{l}ForearmBend"],
        "l_wrist": ["{l}Hand"],
        "l_hip": ["{l}Thigh", "{l}ThighBend"],
        "l_knee": ["{l}Shin"],
        "l_ankle": ["{l}Foot"],
    }),
}

#: Names only one convention uses, to break ties when detecting it.
_MARKERS = {
    "gltrack": ("l_shoulder", "l_elbow", "spine_upper", "l_clavicle"),
    "motionbuilder": ("leftarm", "leftupleg", "leftforearm", "lefttoebase"),
    "3dsmax": ("leftcollar", "leftelbow", "leftwrist", "leftknee", "chest2"),
    "daz": ("lshldr", "lthigh", "lshin", "abdomen", "lcollar"),
}


def _key(name: str) -> str:
    return name.rsplit(":", 1)[-1].rsplit("|", 1)[-1].lower()


def _resolve(table: dict, names) -> tuple[dict, list]:
    by_key = {}
    for n in names:
        by_key.setdefault(_key(n), n)
    found, missing, used = {}, [], set()
    for canon in JOINT_NAMES:
        hit = next((by_key[_key(c)] for c in table.get(canon, ())
                    if _key(c) in by_key and by_key[_key(c)] not in used), None)
        if hit is None:
            missing.append(canon)
        else:
            found[canon] = hit
            used.add(hit)
    return found, missing


def detect_convention(names) -> str:
    """Name of the convention (key of :data:`CONVENTIONS`) that fits ``names`` best.

    Parameters
    ----------
    names : iterable of str, BVH joint names

    Raises
    ------
    ValueError if no convention maps a majority of the canonical joints.
    """
    names = list(names)
    keys = {_key(n) for n in names}
    scores = {}
    for conv, table in CONVENTIONS.items():
        found, _ = _resolve(table, names)
        scores[conv] = (len(found), sum(m in keys for m in _MARKERS[conv]))
    best = max(scores, key=lambda c: scores[c])
    if scores[best][0] < len(JOINT_NAMES) // 2 + 1:
        raise ValueError(f"unknown joint-name convention (best guess {best!r} maps only "
                         f"{scores[best][0]} of {len(JOINT_NAMES)} joints); joints are "
                         f"{', '.join(names)}; pass mapping= explicitly")
    log.debug("joint names look like the %s convention (scores %s)", best, scores)
    return best


def joint_map(names, mapping: dict | None = None, convention: str | None = None) -> dict:
    """Map every canonical gltrack joint onto a BVH joint name.

    Parameters
    ----------
    names : iterable of str
        Joint names of the BVH file.
    mapping : dict, optional
        Overrides ``{canonical: bvh_name}`` (a ``--map`` option); entries win over the
        detected convention. Unknown canonical keys or BVH names raise ``ValueError``.
    convention : str, optional
        Force a key of :data:`CONVENTIONS` instead of detecting it.

    Returns
    -------
    dict canonical name -> BVH joint name, for all :data:`~gltrack.body.skeleton.JOINT_NAMES`.

    Raises
    ------
    ValueError listing the canonical joints that could not be mapped.
    """
    names = list(names)
    mapping = dict(mapping or {})
    bad_keys = sorted(set(mapping) - set(JOINT_NAMES))
    if bad_keys:
        raise ValueError(f"mapping has unknown canonical joints {bad_keys}; canonical joints are "
                         f"{', '.join(JOINT_NAMES)}")
    bad_vals = sorted(v for v in mapping.values() if v not in names)
    if bad_vals:
        raise ValueError(f"mapping names BVH joints that are not in the file: {bad_vals}")
    if convention is None:
        try:
            convention = detect_convention(names)
        except ValueError:
            if len(mapping) < len(JOINT_NAMES):
                raise
            convention = None
    elif convention not in CONVENTIONS:
        raise ValueError(f"unknown convention {convention!r}; choose one of "
                         f"{', '.join(CONVENTIONS)}")
    table = dict(CONVENTIONS[convention]) if convention else {}
    table.update({k: [v] for k, v in mapping.items()})
    found, missing = _resolve(table, names)
    if missing:
        raise ValueError(f"cannot map canonical joints {missing} onto the BVH joints "
                         f"({convention or 'explicit mapping'} convention); pass mapping= for them")
    dup = {v for v in found.values() if list(found.values()).count(v) > 1}
    if dup:
        raise ValueError(f"BVH joints mapped to several canonical joints: {sorted(dup)}")
    return found
