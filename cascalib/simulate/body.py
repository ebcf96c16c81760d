"""Body model: segment lengths from a person's height and the assembly of the 26 canonical joints.

Segment lengths are fixed fractions of the standing height ``H`` (Drillis & Contini 1966, as
tabulated in Winter, *Biomechanics and Motor Control of Human Movement*, Fig. 4.1): shoulder
height 0.818 H, hip (greater trochanter) 0.530 H, knee 0.285 H, ankle 0.039 H, upper arm 0.186 H,
forearm 0.146 H, foot length 0.152 H. Keypoint detectors place the hips and shoulders a little
inside the anatomical widths; the widths below are those of typical COCO/Halpe annotations.

``H`` is the height of the head top above the ground when standing straight.

All functions here are vectorised over time: every per-time input has a leading axis ``T``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cascalib.skeletons import CANONICAL_INDEX

__all__ = ["BodyModel", "two_bone_ik", "assemble_pose"]

J = CANONICAL_INDEX


@dataclass(frozen=True)
class BodyModel:
    """Segment lengths (metres) of one person, derived from the height.

    Parameters
    ----------
    height : float
        Standing height, ground to head top (m).
    """

    height: float

    @property
    def ankle_height(self) -> float:
        """Height of the ankle joint above the ground when the foot is flat."""
        return 0.039 * self.height

    @property
    def thigh(self) -> float:
        return (0.530 - 0.285) * self.height

    @property
    def shank(self) -> float:
        return (0.285 - 0.039) * self.height

    @property
    def leg(self) -> float:
        return self.thigh + self.shank

    @property
    def trunk(self) -> float:
        """Mid-hip to neck (mid-shoulder)."""
        return (0.818 - 0.530) * self.height

    @property
    def upper_arm(self) -> float:
        return 0.186 * self.height

    @property
    def forearm(self) -> float:
        return 0.146 * self.height

    @property
    def hip_half_width(self) -> float:
        return 0.060 * self.height

    @property
    def shoulder_half_width(self) -> float:
        return 0.103 * self.height

    @property
    def standing_hip_height(self) -> float:
        """Mid-hip height when standing with slightly soft knees (98.5 % of full leg reach)."""
        return self.ankle_height + 0.985 * self.leg

    def head_offsets(self) -> dict[str, tuple[float, float, float]]:
        """Head joints relative to the neck as (up, forward, left) in the head frame."""
        h = self.height
        return {
            "head_top": (0.182 * h, 0.0, 0.0),
            "nose": (0.090 * h, 0.060 * h, 0.0),
            "left_eye": (0.118 * h, 0.045 * h, 0.019 * h),
            "right_eye": (0.118 * h, 0.045 * h, -0.019 * h),
            "left_ear": (0.110 * h, -0.005 * h, 0.045 * h),
            "right_ear": (0.110 * h, -0.005 * h, -0.045 * h),
        }

    def foot_offsets(self, side: int) -> dict[str, tuple[float, float, float]]:
        """Foot joints relative to the ankle as (forward, left, up) in the foot frame.

        ``side`` is +1 for the left foot, -1 for the right; the big toe lies medially.
        """
        h = self.height
        down = -0.033 * h  # toes and heel ~1 cm above the ground when the ankle is at 0.039 H
        name = "left" if side > 0 else "right"
        return {
            f"{name}_heel": (-0.030 * h, 0.0, down),
            f"{name}_big_toe": (0.115 * h, -side * 0.012 * h, down),
            f"{name}_small_toe": (0.095 * h, side * 0.022 * h, down),
        }


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def two_bone_ik(root: NDArray[np.float64], end: NDArray[np.float64], a: float, b: float,
                hint: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Middle joint of a two-segment chain (hip-knee-ankle) with exact segment lengths.

    Parameters
    ----------
    root, end : ndarray, shape (T, 3)
        Chain root (hip) and desired end (ankle).
    a, b : float
        Lengths root-middle and middle-end.
    hint : ndarray, shape (T, 3)
        Direction the middle joint bends towards (the knee points forward).

    Returns
    -------
    middle : ndarray, shape (T, 3)
    end : ndarray, shape (T, 3)
        The end actually reached: equal to the input unless it was out of reach (then it is
        pulled onto the reachable sphere so both segment lengths stay exact).
    """
    d_vec = end - root
    d = np.linalg.norm(d_vec, axis=-1, keepdims=True)
    u = d_vec / np.maximum(d, 1e-12)
    d_c = np.clip(d, abs(a - b) + 1e-9, a + b - 1e-9)
    cos_a = (a * a + d_c * d_c - b * b) / (2 * a * d_c)
    sin_a = np.sqrt(np.clip(1 - cos_a * cos_a, 0.0, None))
    v = hint - np.sum(hint * u, axis=-1, keepdims=True) * u
    v = _unit(v)
    middle = root + a * (cos_a * u + sin_a * v)
    reached = root + d_c * u
    return middle, reached


def _frame(heading: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """Forward, left and up unit vectors (T, 3) of a body with yaw ``heading`` (T,)."""
    z = np.zeros_like(heading)
    fwd = np.stack([np.cos(heading), np.sin(heading), z], axis=-1)
    left = np.stack([-np.sin(heading), np.cos(heading), z], axis=-1)
    up = np.stack([z, z, np.ones_like(heading)], axis=-1)
    return fwd, left, up


def _arm_dir(flex: NDArray[np.float64], abduct: float, fwd: NDArray[np.float64],
             out: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit arm direction: hanging down, flexed forward by ``flex`` (T,), abducted sideways."""
    down = np.array([0.0, 0.0, -1.0])
    sag = np.cos(flex)[:, None] * down + np.sin(flex)[:, None] * fwd
    return np.cos(abduct) * sag + np.sin(abduct) * out


def assemble_pose(body: BodyModel, pelvis: NDArray[np.float64], heading: NDArray[np.float64],
                  ankles: dict[int, NDArray[np.float64]],
                  foot_yaw: dict[int, NDArray[np.float64]],
                  foot_pitch: dict[int, NDArray[np.float64]],
                  posture: dict[str, NDArray[np.float64]]) -> NDArray[np.float64]:
    """World positions of the 26 canonical joints over time.

    Parameters
    ----------
    body : BodyModel
    pelvis : ndarray, shape (T, 3)
        Mid-hip position.
    heading : ndarray, shape (T,)
        Body yaw (rad, world x axis = 0).
    ankles : dict side -> ndarray (T, 3)
        Desired ankle positions (side +1 left, -1 right); reached exactly when within leg reach.
    foot_yaw, foot_pitch : dict side -> ndarray (T,)
        Foot orientation (pitch > 0: toes down).
    posture : dict of ndarray (T,)
        ``pelvis_yaw``, ``trunk_pitch`` (forward bend, rad), ``arm_flex`` left/right
        (``arm_flex_l``, ``arm_flex_r``), ``elbow_flex_l``, ``elbow_flex_r``.

    Returns
    -------
    joints : ndarray, shape (T, 26, 3)
    """
    T = pelvis.shape[0]
    out = np.empty((T, 26, 3))
    fwd, left, up = _frame(heading)
    out[:, J["mid_hip"]] = pelvis
    p_fwd, p_left, _ = _frame(heading + posture["pelvis_yaw"])
    for side, name in ((1, "left"), (-1, "right")):
        hip = pelvis + side * body.hip_half_width * p_left
        out[:, J[f"{name}_hip"]] = hip
        hint = _unit(fwd + 0.15 * side * left)  # knees forward and slightly out
        knee, ankle = two_bone_ik(hip, ankles[side], body.thigh, body.shank, hint)
        out[:, J[f"{name}_knee"]] = knee
        out[:, J[f"{name}_ankle"]] = ankle
        f_fwd, f_left, _ = _frame(foot_yaw[side])
        cp, sp = np.cos(foot_pitch[side])[:, None], np.sin(foot_pitch[side])[:, None]
        ff = cp * f_fwd - sp * up  # toes down for positive pitch
        fu = sp * f_fwd + cp * up
        for joint, (a, l, u) in body.foot_offsets(side).items():
            out[:, J[joint]] = ankle + a * ff + l * f_left + u * fu
    pitch = posture["trunk_pitch"][:, None]
    trunk_dir = np.cos(pitch) * up + np.sin(pitch) * fwd
    neck = pelvis + body.trunk * trunk_dir
    out[:, J["neck"]] = neck
    # Shoulders counter-rotate against the pelvis.
    _, s_left, _ = _frame(heading - posture["pelvis_yaw"])
    for side, name in ((1, "left"), (-1, "right")):
        sh = neck + side * body.shoulder_half_width * s_left
        out[:, J[f"{name}_shoulder"]] = sh
        k = "l" if side > 0 else "r"
        flex, elbow = posture[f"arm_flex_{k}"], posture[f"elbow_flex_{k}"]
        upper = _arm_dir(flex, 0.12, fwd, side * left)
        lower = _arm_dir(flex + elbow, 0.05, fwd, side * left)
        el = sh + body.upper_arm * upper
        out[:, J[f"{name}_elbow"]] = el
        out[:, J[f"{name}_wrist"]] = el + body.forearm * lower
    hp = 0.6 * pitch  # the head stays more upright than the trunk
    h_up = np.cos(hp) * up + np.sin(hp) * fwd
    h_fwd = np.cos(hp) * fwd - np.sin(hp) * up
    for joint, (u, a, l) in body.head_offsets().items():
        out[:, J[joint]] = neck + u * h_up + a * h_fwd + l * left
    return out
