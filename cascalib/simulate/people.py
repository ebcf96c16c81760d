"""Simulated people: heights, smooth random walking paths, pauses, actions and a kinematic gait.

Each person's motion is a function of continuous time, so every camera can sample it at its own
frame times. It is built from

* a *path*: a smooth random curve (or a circle, for the periodic case) sampled every
  :data:`DS` metres of arc length;
* a *timeline* sampled every :data:`DT` seconds: the arc length walked so far ``s(t)`` (walking
  segments at the person's speed with smooth starts and stops, and pauses) and the posture weights
  of the actions done while paused (bend, sit, crouch, raise arms);
* a *gait* that turns ``s`` into foot positions: footprints every half stride alternate left and
  right along the path; a foot stays planted (ankle at constant height) for 60 % of the stride
  and swings to the next footprint in an arc for the other 40 %. The hips follow the path and
  drop where the legs could not reach the planted feet; knees come from two-bone inverse
  kinematics, so hip, knee and ankle angle curves follow from the foot placement. Arms swing
  against the legs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from cascalib.simulate.body import BodyModel, assemble_pose

__all__ = ["PeopleConfig", "Person", "ACTIONS", "make_people"]

DS = 0.02  #: path sampling step (m)
DT = 0.01  #: timeline sampling step (s)
STANCE = 0.6  #: fraction of the stride a foot is planted
RAMP = 0.6  #: seconds to speed up from standing or to stop

#: Posture targets of the actions (applied while paused, faded in and out):
#: (pelvis drop as fraction of standing hip height, pelvis moved back (m per m of height),
#:  trunk pitch (rad), arm flexion (rad)).
ACTIONS: dict[str, tuple[float, float, float, float]] = {
    "stand": (0.0, 0.0, 0.0, 0.0),
    "bend": (0.05, 0.06, 1.25, 0.5),
    "sit": (0.45, 0.15, 0.15, 0.3),
    "crouch": (0.50, 0.10, 0.55, 0.6),
    "raise_arms": (0.0, 0.0, 0.0, 2.8),
}


class PeopleConfig(BaseModel):
    """Who is in the scene and how they move."""

    model_config = ConfigDict(extra="forbid")

    n_persons: int = Field(default=5, ge=1, le=20, description="Number of persons.")
    height_mean: float = Field(default=1.70, gt=0.5, lt=2.5, description="Mean body height (m).")
    height_sd: float = Field(default=0.07, ge=0.0, lt=0.5, description="Body height s.d. (m).")
    speed_range: tuple[float, float] = Field(
        default=(0.8, 1.6),
        description="Walking speed range (m/s); each person walks at one speed.")
    area: tuple[float, float] = Field(
        default=(8.0, 8.0), description="Capture area (x, y) size in m, centred on the origin.")
    curviness: float = Field(
        default=0.2, ge=0.0,
        description="s.d. of the path curvature (rad/m, correlated over ~3 m); "
        "0 walks straight.")
    walk_mean_s: float = Field(
        default=8.0, gt=0.0,
        description="Mean duration of a walking bout (s).")
    pause_prob: float = Field(
        default=0.3, ge=0.0, le=1.0, description="Probability that a walking bout ends in a pause.")
    pause_range_s: tuple[float, float] = Field(
        default=(1.5, 5.0), description="Duration range of a pause (s).")
    action_prob: float = Field(
        default=0.4, ge=0.0, le=1.0,
        description="Probability that a pause is spent on a non-standing action.")
    turn_prob: float = Field(
        default=0.5, ge=0.0, le=1.0, description="Probability that a person turns the body on the "
        "spot (30-90 deg, feet planted) during a pause.")
    actions: tuple[str, ...] = Field(
        default=("bend", "sit", "crouch", "raise_arms"), description="Actions to draw from.")
    periodic: bool = Field(
        default=False,
        description="Walk in circles at constant speed (the paper's failure case for "
        "synchronisation, Sec. 5.1).")
    circle_radius: tuple[float, float] = Field(
        default=(1.5, 2.5), description="Circle radius range (m) when periodic.")
    circle_wobble_m: float = Field(
        default=0.0, ge=0.0, lt=1.0, description="When periodic: each lap's radius wobbles by "
        "this s.d. (m), like a person walking the same circuit again (a perfect circle at a "
        "constant speed looks the same at every time shift, up to a rotation about its centre "
        "and the gait phase: no method can synchronise it; the paper's Human3.6M walkers vary).")
    walk_trunk_pitch_rad: float = Field(
        default=0.06, ge=0.0, le=0.3,
        description="Forward lean of the trunk at full walking speed (rad; 0.06 = 3.4 deg, "
        "normal gait leans 2-5 deg): the shoulders and head are 3-4 cm ahead of the feet, "
        "which single-view calibration from 'upright' people does not model; 0 for an "
        "upright walker.")


@dataclass(frozen=True)
class Person:
    """One simulated person: body, path and timeline; :meth:`joints` samples the motion.

    Attributes
    ----------
    path : ndarray, shape (N, 2)
        Path points every :data:`DS` m of arc length.
    heading : ndarray, shape (N,)
        Path direction at those points (rad).
    s : ndarray, shape (M,)
        Arc length walked at times ``k * DT``.
    posture : ndarray, shape (M, 6)
        Action posture targets (see :data:`ACTIONS`) times their fade weight, the body yaw
        relative to the path (turning on the spot) and the feet-together weight.
    """

    body: BodyModel
    speed: float
    stride: float
    path: NDArray[np.float64]
    heading: NDArray[np.float64]
    s: NDArray[np.float64]
    posture: NDArray[np.float64]
    actions: tuple[tuple[float, float, str], ...]
    trunk_pitch: float  # forward trunk lean at full walking speed (rad)

    @property
    def height(self) -> float:
        return self.body.height

    def arc_length(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Arc length walked at times ``t`` (s), shape like ``t``."""
        return np.interp(t / DT, np.arange(self.s.size), self.s)

    def speed_at(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Walking speed (m/s) at times ``t``."""
        v = np.gradient(self.s, DT)
        return np.interp(t / DT, np.arange(self.s.size), v)

    def _path_at(self, s: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        i = s / DS
        k = np.arange(self.path.shape[0])
        xy = np.stack([np.interp(i, k, self.path[:, 0]), np.interp(i, k, self.path[:, 1])], -1)
        h = np.interp(i, k, np.unwrap(self.heading))
        return xy, h

    def _foot(self, s: NDArray[np.float64], side: int) -> tuple[NDArray[np.float64], ...]:
        """Ankle position (T, 3), foot yaw and pitch (T,) of one foot at arc lengths ``s``."""
        phase0 = 0.0 if side > 0 else 0.5
        q = s / self.stride - phase0 + STANCE / 2
        n = np.floor(q)
        r = q - n
        swing = r >= STANCE
        u = np.where(swing, (r - STANCE) / (1 - STANCE), 0.0)
        u_s = u * u * (3 - 2 * u)  # smoothstep: the foot leaves and lands without a jerk
        s0 = (n + phase0) * self.stride
        s1 = s0 + self.stride
        p0, h0 = self._footprint(s0, side)
        p1, h1 = self._footprint(s1, side)
        xy = p0 + u_s[:, None] * (p1 - p0)
        pitch = 0.35 * np.sin(2 * np.pi * u) * swing  # toes down at push-off, up at landing
        lift = 0.045 * self.height * np.sin(np.pi * u)
        # Raise the ankle further where the pitched-down toes would touch the ground.
        toe_drop = self.height * (0.115 * np.sin(pitch) + 0.033 * (np.cos(pitch) - 1))
        z = self.body.ankle_height + np.maximum(lift, toe_drop)
        yaw = h0 + u_s * (h1 - h0)
        return np.column_stack([xy, z]), yaw, pitch

    def _footprint(self, s: NDArray[np.float64], side: int) -> tuple[NDArray[np.float64], ...]:
        xy, h = self._path_at(s)
        left = np.stack([-np.sin(h), np.cos(h)], -1)
        return xy + side * 0.055 * self.height * left, h

    def joints(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """World positions of the 26 canonical joints at times ``t`` (s), shape (T, 26, 3)."""
        t = np.asarray(t, dtype=np.float64)
        s = self.arc_length(t)
        xy, heading = self._path_at(s)
        speed_frac = np.clip(self.speed_at(t) / self.speed, 0.0, 1.0)
        k = np.arange(self.s.size)
        post = np.stack([np.interp(t / DT, k, self.posture[:, i])
                         for i in range(self.posture.shape[1])], -1)
        ankles, yaw, pitch = {}, {}, {}
        for side in (1, -1):
            ankles[side], yaw[side], pitch[side] = self._foot(s, side)
        # While paused, the trailing (left) foot steps up beside the leading one and the body
        # moves over both feet.
        xy = xy + self._step_together(post[:, 5], ankles, yaw)[:, None] * np.stack(
            [np.cos(heading), np.sin(heading)], -1)
        heading = heading + post[:, 4]  # turned on the spot while paused
        fwd = np.stack([np.cos(heading), np.sin(heading)], -1)
        left = np.stack([-np.sin(heading), np.cos(heading)], -1)
        w = 2 * np.pi * s / self.stride
        # Hips sway over the stance foot and are moved back when sitting or bending.
        pelvis_xy = (xy + (0.012 * self.height * np.cos(w) * speed_frac)[:, None] * left
                     - (post[:, 1] * self.height)[:, None] * fwd)
        # Walking with softer knees (mid-stance flexion) keeps the hip bob near real 4-6 cm.
        drop = post[:, 0] + 0.03 * speed_frac
        pelvis_z = self._pelvis_height(pelvis_xy, heading, ankles, drop)
        pelvis = np.column_stack([pelvis_xy, pelvis_z])
        swing = 0.35 * speed_frac * np.sin(w)  # left arm forward when the right leg is
        posture = {
            "pelvis_yaw": 0.07 * speed_frac * np.sin(w),
            "trunk_pitch": self.trunk_pitch * speed_frac + post[:, 2],
            "arm_flex_l": swing + post[:, 3], "arm_flex_r": -swing + post[:, 3],
            "elbow_flex_l": 0.25 + 0.25 * speed_frac * (1 + np.sin(w)),
            "elbow_flex_r": 0.25 + 0.25 * speed_frac * (1 - np.sin(w)),
        }
        return assemble_pose(self.body, pelvis, heading, ankles, yaw, pitch, posture)

    def _step_together(self, g: NDArray[np.float64], ankles: dict[int, NDArray[np.float64]],
                       yaw: dict[int, NDArray[np.float64]]) -> NDArray[np.float64]:
        """Move the left foot beside the right one by weight ``g`` (T,), in place.

        A pause starts in double support with the left foot a quarter stride behind the body
        and the right one a quarter stride ahead; at ``g = 1`` the feet stand side by side under
        the body. Returns how far (m) the body moves forward.
        """
        if not np.any(g > 0):
            return np.zeros_like(g)
        right, ry = ankles[-1], yaw[-1]
        beside = right[:, :2] + 2 * 0.055 * self.height * np.stack([-np.sin(ry), np.cos(ry)], -1)
        gs = g * g * (3 - 2 * g)
        a = ankles[1]
        a[:, :2] += gs[:, None] * (beside - a[:, :2])
        a[:, 2] += 0.045 * self.height * np.sin(np.pi * g)
        yaw[1] = yaw[1] + gs * (ry - yaw[1])
        return 0.25 * self.stride * gs

    def _pelvis_height(self, pelvis_xy: NDArray[np.float64], heading: NDArray[np.float64],
                       ankles: dict[int, NDArray[np.float64]], drop: NDArray[np.float64]
                       ) -> NDArray[np.float64]:
        """Nominal hip height, lowered by actions and wherever a leg could not reach its foot."""
        b = self.body
        z = b.standing_hip_height * (1 - drop)
        left = np.stack([-np.sin(heading), np.cos(heading)], -1)
        reach = 0.998 * b.leg
        for side in (1, -1):
            hip_xy = pelvis_xy + side * b.hip_half_width * left
            d2 = np.sum((hip_xy - ankles[side][:, :2]) ** 2, -1)
            z = np.minimum(z, ankles[side][:, 2] + np.sqrt(np.clip(reach**2 - d2, 0, None)))
        return z


def _random_path(cfg: PeopleConfig, length: float, start: NDArray[np.float64],
                 rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A smooth random path of ``length`` metres that stays inside the capture area."""
    n = int(np.ceil(length / DS)) + 2
    half = np.asarray(cfg.area) / 2
    # Curvature: white noise smoothed over ~3 m, so the path turns gently.
    kernel = np.exp(-0.5 * (np.arange(-300, 301) * DS / 1.2) ** 2)
    noise = rng.standard_normal(n + kernel.size)
    kappa = np.convolve(noise, kernel / np.sqrt(np.sum(kernel**2)), "same")[:n]
    kappa = (kappa * cfg.curviness).tolist()
    pts = np.empty((n, 2))
    head = np.empty(n)
    x, y = float(start[0]), float(start[1])
    h = float(rng.uniform(-np.pi, np.pi))
    hx, hy = float(half[0]), float(half[1])
    # Sequential in arc length (the steering depends on the position), but cheap: a few
    # thousand scalar steps per person, independent of the number of cameras and frames.
    for i in range(n):
        pts[i, 0], pts[i, 1], head[i] = x, y, h
        turn = kappa[i]
        out = max(abs(x) / hx, abs(y) / hy) - 0.7  # > 0 in the outer part of the area
        if out > 0:  # steer back towards the centre, harder the farther out
            d = (math.atan2(-y, -x) - h + math.pi) % (2 * math.pi) - math.pi
            turn += min(out / 0.3, 1.0) * 1.5 * d
        h += turn * DS
        x += DS * math.cos(h)
        y += DS * math.sin(h)
    return pts, head


def _circle_path(cfg: PeopleConfig, length: float, rng: np.random.Generator
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r = rng.uniform(*cfg.circle_radius)
    half = np.asarray(cfg.area) / 2
    c = rng.uniform(-1, 1, 2) * np.maximum(half - r, 0.0) * 0.5
    s = np.arange(int(np.ceil(length / DS)) + 2) * DS
    a0 = rng.uniform(-np.pi, np.pi)
    direction = rng.choice([-1.0, 1.0])
    a = a0 + direction * s / r
    if cfg.circle_wobble_m <= 0:  # (no draws: scenes without wobble stay as they were)
        pts = c + r * np.stack([np.cos(a), np.sin(a)], -1)
        return pts, a + direction * np.pi / 2
    # per lap, radius terms of 2 and 3 waves around the circle, faded in and out at the lap's
    # ends so that the path stays continuous
    lap = np.floor((a - a0) * direction / (2 * np.pi)).astype(np.int64)
    wob = rng.normal(0, cfg.circle_wobble_m, (int(lap.max()) + 1, 2))[lap]
    frac = (a - a0) * direction / (2 * np.pi) - lap
    blend = 0.5 - 0.5 * np.cos(2 * np.pi * frac)
    rr = r + blend * (wob[:, 0] * np.cos(2 * a) + wob[:, 1] * np.sin(3 * a))
    pts = c + rr[:, None] * np.stack([np.cos(a), np.sin(a)], -1)
    d = np.gradient(pts, axis=0)
    return pts, np.arctan2(d[:, 1], d[:, 0])


def _timeline(cfg: PeopleConfig, duration: float, speed: float, stride: float,
              rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                 list[tuple[float, float, str]]]:
    """Arc length ``s`` and posture (M, 4) every DT seconds, plus (start, end, action) list."""
    m = int(np.ceil(duration / DT)) + 2
    v = np.zeros(m)
    posture = np.zeros((m, 6))
    actions: list[tuple[float, float, str]] = []
    t = 0.0 if cfg.periodic else rng.uniform(0, 1.0)
    # Bouts end in a pause with probability pause_prob, so the time between pauses is
    # exponential with mean walk_mean_s / pause_prob.
    mean_walk = cfg.walk_mean_s / cfg.pause_prob if cfg.pause_prob > 0 else np.inf
    while t < duration:
        walk = duration + 1 if cfg.periodic else min(rng.exponential(mean_walk) + 2 * RAMP,
                                                     duration + 1)
        if walk < duration - t:
            # A bout covers whole strides (the trapezoid speed profile walks speed * (walk -
            # RAMP) metres), so stopping in double support hardly changes the speed.
            n_strides = max(1, round((walk - RAMP) * speed / stride))
            walk = n_strides * stride / speed + RAMP
        i0, i1 = int(t / DT), min(int((t + walk) / DT), m)
        tt = np.arange(i0, i1) * DT - t
        v[i0:i1] = speed * np.clip(np.minimum(tt, walk - tt) / RAMP, 0, 1)
        if cfg.periodic:
            v[:] = speed
            break
        t += walk
        if t < duration:
            pause = rng.uniform(*cfg.pause_range_s)
            j0, j1 = int(t / DT), min(int((t + pause) / DT), m)
            tt = np.arange(j0, j1) * DT - t
            fade = np.clip(np.minimum(tt, pause - tt) / 0.8, 0, 1)
            fade = fade * fade * (3 - 2 * fade)
            if cfg.actions and rng.random() < cfg.action_prob:
                name = str(rng.choice(cfg.actions))
                posture[j0:j1, :4] = fade[:, None] * np.asarray(ACTIONS[name])
                actions.append((t, t + pause, name))
            # step the feet together (0.5 s) and apart again before walking on
            posture[j0:j1, 5] = np.clip(np.minimum(tt, pause - tt) / 0.5, 0, 1)
            if rng.random() < cfg.turn_prob:
                yaw = rng.choice([-1.0, 1.0]) * np.deg2rad(rng.uniform(30.0, 90.0))
                posture[j0:j1, 4] = fade * yaw
            t += pause
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT)])
    s = _snap_stops(s, v, stride)
    return s, posture, actions


def _snap_stops(s: NDArray[np.float64], v: NDArray[np.float64], stride: float
                ) -> NDArray[np.float64]:
    """Stretch each walking bout so it ends in double support (feet apart, both planted).

    A bout ends at a whole number of strides (the gait starts a quarter stride into its cycle,
    so that is where both feet are on the ground); stopping anywhere else would freeze a foot
    in mid-swing.
    """
    moving = v > 1e-9
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts = [0] if moving[0] else []
    starts += [int(e) + 1 for e in edges if moving[e + 1]]
    out = s.copy()
    offset = 0.0
    cur = 0
    for b0 in starts:
        b1 = next((int(e) + 1 for e in edges if e + 1 > b0 and not moving[e + 1]), None)
        if b1 is None:  # still walking when the scene ends
            break
        out[cur:b0] = s[cur:b0] + offset
        s0, s1 = s[b0] + offset, s[b1] + offset
        target = np.round(s1 / stride) * stride
        if target <= s0:
            target += stride
        seg = s[b0:b1 + 1] + offset
        out[b0:b1 + 1] = s0 + (seg - s0) * (target - s0) / max(s1 - s0, 1e-12)
        offset = target - s[b1]
        cur = b1 + 1
    out[cur:] = s[cur:] + offset
    return out


def make_people(cfg: PeopleConfig, duration: float, rng: np.random.Generator) -> list[Person]:
    """Draw ``cfg.n_persons`` people with paths and timelines covering ``duration`` seconds."""
    people = []
    half = np.asarray(cfg.area) / 2
    for _ in range(cfg.n_persons):
        height = float(np.clip(rng.normal(cfg.height_mean, cfg.height_sd), 1.2, 2.2))
        speed = float(rng.uniform(*cfg.speed_range))
        # Step length grows with height and speed (about 0.37 H at 1.3 m/s).
        stride = 2 * height * (0.26 + 0.08 * speed)
        # The walk starts in double support, a quarter stride into the gait cycle.
        s0 = 0.25 * stride
        s, posture, actions = _timeline(cfg, duration, speed, stride, rng)
        s = s + s0
        length = float(s[-1]) + stride + 1.0
        if cfg.periodic:
            path, heading = _circle_path(cfg, length, rng)
        else:
            start = rng.uniform(-0.7, 0.7, 2) * half
            path, heading = _random_path(cfg, length, start, rng)
        people.append(Person(BodyModel(height), speed, stride, path, heading, s, posture,
                             tuple(actions), cfg.walk_trunk_pitch_rad))
    return people
