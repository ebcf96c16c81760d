"""Per-camera clocks: start time, frame rate, drift, late starts and early stops.

World time ``t`` is in seconds. Camera ``c`` starts recording at ``start_c`` and its frame ``k``
is exposed at ``t = start_c + k * (1 + drift_c) / fps_c`` (a positive drift is a slow clock: its
frames are farther apart than nominal). The first camera is the reference; by cascalib's TIME
CONVENTION frame ``k`` of camera ``c`` shows reference frame ``time_rate * k + time_offset`` with

    time_offset = (start_c - start_ref) * fps_ref / (1 + drift_ref)
    time_rate   = fps_ref / fps_c * (1 + drift_c) / (1 + drift_ref)

(the reference camera's drift is drawn as 0, so this is the brief's ``O = (s_c - s_ref) fps_ref``
and ``S = fps_ref / fps_c (1 + drift)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

__all__ = ["TimingConfig", "Clock", "make_clocks", "STANDARD_FPS"]

#: Frame rates of real cameras.
STANDARD_FPS: tuple[float, ...] = (25.0, 30000 / 1001, 30.0, 50.0, 60000 / 1001, 60.0)


class TimingConfig(BaseModel):
    """How the cameras' clocks differ."""

    model_config = ConfigDict(extra="forbid")

    fps: tuple[float, ...] = Field(
        default=(30.0,), description="Frame rates drawn from, per camera (e.g. STANDARD_FPS).")
    fps_in_turn: bool = Field(
        default=False, description="Give the cameras the rates of `fps` in turn (guaranteed mixed "
        "rates) instead of drawing them at random.")
    max_offset_s: float = Field(
        default=3.0, ge=0, description="Start times are spread uniformly over this many seconds.")
    drift_sd: float = Field(
        default=0.0, ge=0, lt=0.01,
        description="s.d. of the relative clock drift (1e-4 = 100 ppm); "
        "the reference camera has none.")
    late_start_prob: float = Field(
        default=0.0, ge=0, le=1, description="Probability that a camera starts late.")
    early_stop_prob: float = Field(
        default=0.0, ge=0, le=1, description="Probability that a camera stops early.")
    late_max_s: float = Field(
        default=10.0, ge=0, description="Max extra delay of a late start / early stop (s).")


@dataclass(frozen=True)
class Clock:
    """One camera's clock.

    Attributes
    ----------
    start : float
        World time of frame 0 (s).
    fps : float
        Nominal frame rate.
    drift : float
        Relative drift: frame spacing is ``(1 + drift) / fps`` seconds.
    n_frames : int
        Number of frames recorded.
    """

    start: float
    fps: float
    drift: float
    n_frames: int

    def frame_times(self) -> NDArray[np.float64]:
        """World time (s) of each frame, shape (n_frames,)."""
        k = np.arange(self.n_frames, dtype=np.float64)
        return np.asarray(self.start + k * ((1 + self.drift) / self.fps), dtype=np.float64)

    def time_offset_rate(self, ref: Clock) -> tuple[float, float]:
        """``(time_offset, time_rate)`` of this clock relative to the reference clock ``ref``."""
        offset = (self.start - ref.start) * ref.fps / (1 + ref.drift)
        rate = ref.fps / self.fps * (1 + self.drift) / (1 + ref.drift)
        return float(offset), float(rate)


def make_clocks(cfg: TimingConfig, n_cameras: int, duration: float,
                rng: np.random.Generator) -> list[Clock]:
    """Draw the clocks of ``n_cameras`` cameras recording within ``[0, duration]`` seconds.

    Each camera starts within ``[0, max_offset_s]`` (later if it starts late) and stops within
    ``max_offset_s`` of the end (earlier if it stops early); the first camera is the reference
    and has no drift.
    """
    clocks = []
    for c in range(n_cameras):
        pick = rng.integers(len(cfg.fps))
        fps = float(cfg.fps[c % len(cfg.fps) if cfg.fps_in_turn else int(pick)])
        drift = 0.0 if c == 0 else float(rng.normal(0, cfg.drift_sd))
        start = rng.uniform(0, cfg.max_offset_s)
        end = duration - rng.uniform(0, cfg.max_offset_s)
        if rng.random() < cfg.late_start_prob:
            start += rng.uniform(0, cfg.late_max_s)
        if rng.random() < cfg.early_stop_prob:
            end -= rng.uniform(0, cfg.late_max_s)
        if end - start < 2.0:  # keep at least two seconds of video
            end = min(duration, start + 2.0)
            start = end - 2.0
        n = int(np.floor((end - start) * fps / (1 + drift))) + 1
        clocks.append(Clock(float(start), fps, drift, n))
    return clocks
