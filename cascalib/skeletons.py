"""Keypoint skeletons of the common 2D pose detectors, mapped onto one canonical joint set.

Every detector numbers its joints differently. The algorithms of the cascade only ever ask for
*named* canonical joints ("left_ankle", "neck", ...), so each skeleton here is a list of the
detector's own joint names plus, per joint, the canonical name it corresponds to (or ``None`` when
the canonical set has no equivalent, e.g. BlazePose's mouth corners).

The canonical set is Halpe-26's joints: COCO-17 plus head top, neck, mid-hip and three points per
foot. Joints that a skeleton lacks but that can be derived (neck = mid-shoulder, mid-hip =
mid-point of the hips) are filled in by :func:`to_canonical`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError

__all__ = [
    "CANONICAL_JOINTS",
    "CANONICAL_INDEX",
    "CANONICAL_BONES",
    "LEFT_RIGHT_PAIRS",
    "Skeleton",
    "SKELETONS",
    "get_skeleton",
    "infer_skeleton",
    "to_canonical",
]

#: The canonical joint names, in the order of the last axis of canonical keypoint arrays.
CANONICAL_JOINTS: tuple[str, ...] = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle",
    "head_top", "neck", "mid_hip",
    "left_big_toe", "right_big_toe", "left_small_toe", "right_small_toe",
    "left_heel", "right_heel",
)  # fmt: skip
CANONICAL_INDEX: dict[str, int] = {name: i for i, name in enumerate(CANONICAL_JOINTS)}

#: Bones of the canonical skeleton as (parent, child) names: used for drawing and bone-length terms.
CANONICAL_BONES: tuple[tuple[str, str], ...] = (
    ("neck", "head_top"), ("neck", "nose"), ("nose", "left_eye"), ("nose", "right_eye"),
    ("left_eye", "left_ear"), ("right_eye", "right_ear"),
    ("neck", "left_shoulder"), ("neck", "right_shoulder"),
    ("left_shoulder", "left_elbow"), ("right_shoulder", "right_elbow"),
    ("left_elbow", "left_wrist"), ("right_elbow", "right_wrist"),
    ("neck", "mid_hip"), ("mid_hip", "left_hip"), ("mid_hip", "right_hip"),
    ("left_hip", "left_knee"), ("right_hip", "right_knee"),
    ("left_knee", "left_ankle"), ("right_knee", "right_ankle"),
    ("left_ankle", "left_heel"), ("right_ankle", "right_heel"),
    ("left_ankle", "left_big_toe"), ("right_ankle", "right_big_toe"),
    ("left_big_toe", "left_small_toe"), ("right_big_toe", "right_small_toe"),
)  # fmt: skip


def _left_right_pairs(names: tuple[str, ...]) -> tuple[tuple[int, int], ...]:
    index = {n: i for i, n in enumerate(names)}
    pairs = []
    for i, n in enumerate(names):
        if n.startswith("left_") and "right_" + n[5:] in index:
            pairs.append((i, index["right_" + n[5:]]))
    return tuple(pairs)


#: (left, right) index pairs in the canonical layout, for symmetry terms and swap detection.
LEFT_RIGHT_PAIRS: tuple[tuple[int, int], ...] = _left_right_pairs(CANONICAL_JOINTS)


@dataclass(frozen=True)
class Skeleton:
    """A detector's joint layout and its mapping onto the canonical joints.

    Parameters
    ----------
    name : str
        Identifier used in files and on the command line (``"coco17"``, ``"body25"`` ...).
    joint_names : tuple of str
        The detector's own joint names, in its order.
    canonical : tuple of (str or None)
        For each joint, the canonical joint it corresponds to, or ``None``.
    """

    name: str
    joint_names: tuple[str, ...]
    canonical: tuple[str | None, ...]
    aliases: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        assert len(self.joint_names) == len(self.canonical), self.name
        mapped = [c for c in self.canonical if c is not None]
        assert len(mapped) == len(set(mapped)), f"{self.name}: canonical joint mapped twice"
        assert all(c in CANONICAL_INDEX for c in mapped), self.name

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def index(self, canonical_name: str) -> int | None:
        """Index of the joint mapped to ``canonical_name`` in this skeleton, or None."""
        try:
            return self.canonical.index(canonical_name)
        except ValueError:
            return None

    @property
    def canonical_indices(self) -> NDArray[np.int64]:
        """Array of shape (n_joints,): canonical index of each joint, -1 where unmapped."""
        return np.array(
            [-1 if c is None else CANONICAL_INDEX[c] for c in self.canonical], dtype=np.int64
        )


_COCO17 = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle",
)  # fmt: skip


def _identity(names: tuple[str, ...]) -> tuple[str | None, ...]:
    return tuple(n if n in CANONICAL_INDEX else None for n in names)


def _build() -> dict[str, Skeleton]:
    sk: list[Skeleton] = []
    sk.append(Skeleton("coco17", _COCO17, _identity(_COCO17), aliases=("coco", "coco_17")))
    halpe = _COCO17 + (
        "head", "neck", "hip", "left_big_toe", "right_big_toe",
        "left_small_toe", "right_small_toe", "left_heel", "right_heel",
    )  # fmt: skip
    halpe_c = _COCO17 + (
        "head_top", "neck", "mid_hip", "left_big_toe", "right_big_toe",
        "left_small_toe", "right_small_toe", "left_heel", "right_heel",
    )  # fmt: skip
    sk.append(Skeleton("halpe26", halpe, halpe_c, aliases=("halpe", "halpe_26")))
    body25 = (
        "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
        "MidHip", "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle",
        "REye", "LEye", "REar", "LEar",
        "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
    )  # fmt: skip
    body25_c = (
        "nose", "neck", "right_shoulder", "right_elbow", "right_wrist",
        "left_shoulder", "left_elbow", "left_wrist",
        "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle",
        "right_eye", "left_eye", "right_ear", "left_ear",
        "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe",
        "right_heel",
    )  # fmt: skip
    sk.append(Skeleton("body25", body25, body25_c, aliases=("body_25", "openpose25")))
    body25b = _COCO17 + (
        "Neck", "HeadTop", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
    )  # fmt: skip
    body25b_c = _COCO17 + (
        "neck", "head_top", "left_big_toe", "left_small_toe", "left_heel",
        "right_big_toe", "right_small_toe", "right_heel",
    )  # fmt: skip
    sk.append(Skeleton("body25b", body25b, body25b_c, aliases=("body_25b",)))
    coco18 = (
        "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
        "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
    )  # fmt: skip
    coco18_c = (
        "nose", "neck", "right_shoulder", "right_elbow", "right_wrist",
        "left_shoulder", "left_elbow", "left_wrist",
        "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle",
        "right_eye", "left_eye", "right_ear", "left_ear",
    )  # fmt: skip
    sk.append(Skeleton("coco18", coco18, coco18_c, aliases=("coco_18", "openpose18")))
    blaze = (
        "nose", "left_eye_inner", "left_eye", "left_eye_outer",
        "right_eye_inner", "right_eye", "right_eye_outer", "left_ear", "right_ear",
        "mouth_left", "mouth_right", "left_shoulder", "right_shoulder",
        "left_elbow", "right_elbow", "left_wrist", "right_wrist",
        "left_pinky", "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb",
        "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
        "left_heel", "right_heel", "left_foot_index", "right_foot_index",
    )  # fmt: skip
    # BlazePose's "foot index" is the tip of the foot: the closest canonical point is the big toe.
    blaze_c = tuple(
        {"left_foot_index": "left_big_toe", "right_foot_index": "right_big_toe"}.get(
            n, n if n in CANONICAL_INDEX else None
        )
        for n in blaze
    )
    sk.append(Skeleton("blazepose33", blaze, blaze_c, aliases=("mediapipe", "blazepose")))
    h36m = (
        "Hip", "RHip", "RKnee", "RFoot", "LHip", "LKnee", "LFoot", "Spine", "Thorax",
        "Neck/Nose", "Head", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
    )  # fmt: skip
    h36m_c = (
        "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee",
        "left_ankle", None, "neck", "nose", "head_top",
        "left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow",
        "right_wrist",
    )  # fmt: skip
    sk.append(Skeleton("h36m17", h36m, h36m_c, aliases=("h36m", "human36m")))
    # COCO-WholeBody (mmpose/rtmlib RTMW, DWPose): body, 6 foot points, then 68 face and 2 x 21
    # hand points that have no canonical joint.
    wholebody = _COCO17 + (
        "left_big_toe", "left_small_toe", "left_heel",
        "right_big_toe", "right_small_toe", "right_heel",
    ) + tuple(f"face_{i}" for i in range(68)) + tuple(
        f"{side}_hand_{i}" for side in ("left", "right") for i in range(21))  # fmt: skip
    sk.append(Skeleton("coco_wholebody133", wholebody, _identity(wholebody),
                       aliases=("coco_wholebody", "wholebody", "rtmw", "dwpose")))
    return {s.name: s for s in sk}


#: All known skeletons by canonical name.
SKELETONS: dict[str, Skeleton] = _build()
_ALIASES: dict[str, str] = {
    alias: s.name for s in SKELETONS.values() for alias in (s.name, *s.aliases)
}


def get_skeleton(name: str | Skeleton) -> Skeleton:
    """Look a skeleton up by name or alias (case-insensitive).

    Raises
    ------
    InputError
        If the name is unknown; the message lists the known names.
    """
    if isinstance(name, Skeleton):
        return name
    key = name.lower().replace("-", "_")
    key = _ALIASES.get(key, _ALIASES.get(key.replace("_", ""), key))
    if key not in SKELETONS:
        raise InputError(
            f"unknown skeleton {name!r}; known: {', '.join(sorted(SKELETONS))}", field="skeleton"
        )
    return SKELETONS[key]


def _midpoint_distances(kp: NDArray[np.float64], mid: int, a: int, b: int
                        ) -> NDArray[np.float64]:
    """Distances of joint ``mid`` from the midpoint of ``a`` and ``b``, relative to |a-b|."""
    m = 0.5 * (kp[..., a, :2] + kp[..., b, :2])
    span = np.linalg.norm(kp[..., a, :2] - kp[..., b, :2], axis=-1)
    d = np.linalg.norm(kp[..., mid, :2] - m, axis=-1) / np.maximum(span, 1e-9)
    return d[np.isfinite(d)]


def _midpoint_error(kp: NDArray[np.float64], mid: int, a: int, b: int) -> float:
    """Median distance of joint ``mid`` from the midpoint of ``a`` and ``b``, relative to |a-b|."""
    d = _midpoint_distances(kp, mid, a, b)
    return float(np.median(d)) if d.size else np.inf


def infer_skeleton(n_joints: int, keypoints: NDArray[np.float64] | None = None) -> Skeleton:
    """Pick the skeleton from the number of joints, and from the keypoints where that is ambiguous.

    17 joints are COCO-17 unless the keypoints look like Human3.6M (joint 0 at the mid-point of
    joints 1 and 4, its hips); 25 joints are BODY_25 when joints 1 and 8 lie at the mid-points of
    the shoulders (2, 5) and hips (9, 12), else BODY_25B.

    Parameters
    ----------
    n_joints : int
        Number of joints per person in the file.
    keypoints : ndarray, shape (..., n_joints, >=2), optional
        Sample keypoints (NaN where missing) used to break ties.

    Raises
    ------
    InputError
        If no known skeleton has ``n_joints`` joints, or the ambiguity cannot be resolved.
    """
    by_count: dict[int, list[str]] = {}
    for s in SKELETONS.values():
        by_count.setdefault(s.n_joints, []).append(s.name)
    if n_joints not in by_count:
        known = ", ".join(f"{n} ({'/'.join(v)})" for n, v in sorted(by_count.items()))
        raise InputError(
            f"no known skeleton has {n_joints} joints; known joint counts: {known}",
            field="keypoints",
        )
    if n_joints == 17:
        if keypoints is not None and _midpoint_error(keypoints, 0, 1, 4) < 0.15:
            return SKELETONS["h36m17"]
        return SKELETONS["coco17"]
    if n_joints == 25:
        if keypoints is None:
            return SKELETONS["body25"]
        # BODY_25 puts its neck (1) and mid-hip (8) half-way between the shoulders (2, 5) and
        # hips (9, 12). BODY_25B's joint 17 is the *upper* neck, half a shoulder span above the
        # shoulders, so it cannot serve as the BODY_25B test: decide on BODY_25's midpoints alone.
        d25 = np.concatenate([_midpoint_distances(keypoints, 1, 2, 5),
                              _midpoint_distances(keypoints, 8, 9, 12)])
        if d25.size:
            return SKELETONS["body25"] if np.median(d25) < 0.25 else SKELETONS["body25b"]
        if np.isfinite(_midpoint_error(keypoints, 17, 5, 6)):
            return SKELETONS["body25b"]
        raise InputError(
            "25 joints could be OpenPose BODY_25 or BODY_25B and the keypoints do not tell; "
            "give the skeleton explicitly",
            field="skeleton",
        )
    return SKELETONS[by_count[n_joints][0]]


def to_canonical(keypoints: NDArray[np.float64], skeleton: Skeleton) -> NDArray[np.float64]:
    """Re-order keypoints of any skeleton into the canonical layout.

    Parameters
    ----------
    keypoints : ndarray, shape (..., skeleton.n_joints, C)
        Keypoints in the skeleton's own order (C = 3 for x, y, confidence; NaN where missing).
    skeleton : Skeleton
        The layout of ``keypoints``.

    Returns
    -------
    ndarray, shape (..., len(CANONICAL_JOINTS), C)
        NaN where the skeleton has no such joint. ``neck`` and ``mid_hip`` are derived as the
        mid-points of the shoulders and hips when the skeleton lacks them (confidence: the smaller
        of the two).
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    out = np.full(kp.shape[:-2] + (len(CANONICAL_JOINTS), kp.shape[-1]), np.nan)
    src = skeleton.canonical_indices
    mask = src >= 0
    out[..., src[mask], :] = kp[..., np.flatnonzero(mask), :]
    for mid, (a, b) in (("neck", ("left_shoulder", "right_shoulder")),
                        ("mid_hip", ("left_hip", "right_hip"))):  # fmt: skip
        if skeleton.index(mid) is None:
            pa, pb = out[..., CANONICAL_INDEX[a], :], out[..., CANONICAL_INDEX[b], :]
            m = 0.5 * (pa + pb)
            if kp.shape[-1] > 2:
                m[..., 2:] = np.minimum(pa[..., 2:], pb[..., 2:])
            out[..., CANONICAL_INDEX[mid], :] = m
    return out
