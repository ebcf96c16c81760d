"""Keypoint tracks: the 2D detections of one camera, the input of the whole cascade.

Axes, everywhere in cascalib: ``keypoints[f, p, j, c]`` with ``f`` the frame (row ``f`` is video
frame ``f`` of that camera), ``p`` a person slot within the frame, ``j`` the joint in the skeleton's
own order and ``c`` in (x, y, confidence). Pixels, origin at the top-left pixel's centre
(OpenCV's convention). NaN marks a missing joint or an empty person slot. Persons need not be
identified across frames or across cameras; when a detector tracks them, ``track_ids[f, p]``
holds the per-camera id (``-1`` where unknown).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.skeletons import CANONICAL_INDEX, Skeleton, get_skeleton, to_canonical

__all__ = ["Tracks", "parse_image_size", "stack_persons"]

#: How far outside the image a detection may lie before the image size is declared inconsistent,
#: as a fraction of the image size. Detectors extrapolate truncated limbs a little past the border.
IMAGE_MARGIN = 0.25


def parse_image_size(value: str | tuple[int, int] | list[int], *, field_name: str = "image_size",
                     camera: str | None = None) -> tuple[int, int]:
    """Parse ``"1920x1080"`` (or a ``(W, H)`` pair) into ``(width, height)``.

    Raises
    ------
    InputError
        If the value is not two positive integers.
    """
    try:
        if isinstance(value, str):
            w_s, h_s = value.lower().replace(" ", "").split("x")
            w, h = int(w_s), int(h_s)
        else:
            w, h = (int(v) for v in value)
    except (ValueError, TypeError):
        raise InputError(f"image size must look like 1920x1080, got {value!r}",
                         field=field_name, camera=camera) from None
    if w <= 0 or h <= 0:
        raise InputError(f"image size must be positive, got {w}x{h}", field=field_name,
                         camera=camera)
    return w, h


@dataclass(frozen=True, eq=False)
class Tracks:
    """The 2D keypoint detections of one camera.

    Parameters
    ----------
    camera : str
        Camera name (unique within a session).
    keypoints : ndarray, shape (n_frames, n_persons, n_joints, 3)
        x, y (pixels) and confidence (>= 0); NaN where missing.
    skeleton : Skeleton
        The joint layout of ``keypoints``.
    image_size : (int, int) or None
        (width, height) in pixels, None when not known yet.
    fps : float or None
        Nominal frame rate.
    timestamps : ndarray, shape (n_frames,), optional
        Capture time of each frame in seconds (any origin), when the source has them.
    track_ids : ndarray of int, shape (n_frames, n_persons), optional
        Per-camera person ids, -1 where unknown.
    source : str, optional
        File or folder the tracks were read from (used in error messages).
    """

    camera: str
    keypoints: NDArray[np.float64]
    skeleton: Skeleton
    image_size: tuple[int, int] | None = None
    fps: float | None = None
    timestamps: NDArray[np.float64] | None = None
    track_ids: NDArray[np.int64] | None = None
    source: str | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "skeleton", get_skeleton(self.skeleton))
        kp = np.asarray(self.keypoints, dtype=np.float64)
        object.__setattr__(self, "keypoints", kp)
        if self.image_size is not None:
            object.__setattr__(self, "image_size",
                               parse_image_size(self.image_size, camera=self.camera))
        if self.timestamps is not None:
            object.__setattr__(self, "timestamps", np.asarray(self.timestamps, np.float64))
        if self.track_ids is not None:
            object.__setattr__(self, "track_ids", np.asarray(self.track_ids, np.int64))
        self._validate()

    # -- validation -------------------------------------------------------------------------
    def _error(self, message: str, *, frame: int | None = None,
               field: str | None = None) -> InputError:
        return InputError(message, file=self.source, camera=self.camera, frame=frame,
                          field=field)

    def _validate(self) -> None:
        kp = self.keypoints
        if not self.camera or not isinstance(self.camera, str):
            raise self._error("camera name must be a non-empty string", field="camera")
        if kp.ndim != 4 or kp.shape[-1] != 3:
            raise self._error(f"keypoints must have shape (frames, persons, joints, 3), got "
                              f"{kp.shape}", field="keypoints")
        if kp.shape[2] != self.skeleton.n_joints:
            raise self._error(f"skeleton {self.skeleton.name} has {self.skeleton.n_joints} "
                              f"joints, keypoints have {kp.shape[2]}", field="keypoints")
        if kp.shape[0] == 0 or not np.isfinite(kp[..., :2]).any():
            raise self._error("no detections: the sequence is empty", field="keypoints")
        bad = np.isinf(kp)
        if bad.any():
            raise self._error("infinite coordinate or confidence",
                              frame=int(np.argwhere(bad)[0][0]), field="keypoints")
        # A joint is either fully present (x, y, c finite) or fully missing.
        partial = np.isnan(kp).any(-1) & ~np.isnan(kp).all(-1)
        if partial.any():
            raise self._error("joint with NaN in some but not all of x, y, confidence",
                              frame=int(np.argwhere(partial)[0][0]), field="keypoints")
        neg = kp[..., 2] < 0
        if neg.any():
            f = int(np.argwhere(neg)[0][0])
            raise self._error(f"negative confidence {kp[..., 2][neg][0]:g}", frame=f,
                              field="confidence")
        if self.image_size is not None:
            self._check_inside_image()
        if self.fps is not None and not (np.isfinite(self.fps) and self.fps > 0):
            raise self._error(f"frame rate must be positive, got {self.fps}", field="fps")
        if self.timestamps is not None:
            ts = self.timestamps
            if ts.shape != (kp.shape[0],):
                raise self._error(f"{ts.shape[0]} timestamps for {kp.shape[0]} frames",
                                  field="timestamps")
            finite = ts[np.isfinite(ts)]
            if finite.size > 1 and np.any(np.diff(finite) <= 0):
                f = int(np.flatnonzero(np.isfinite(ts))[np.argmax(np.diff(finite) <= 0) + 1])
                raise self._error("timestamps must increase", frame=f, field="timestamps")
        if self.track_ids is not None and self.track_ids.shape != kp.shape[:2]:
            raise self._error(f"track_ids shape {self.track_ids.shape} does not match "
                              f"(frames, persons) = {kp.shape[:2]}", field="track_ids")

    def _check_inside_image(self) -> None:
        assert self.image_size is not None
        w, h = self.image_size
        x, y = self.keypoints[..., 0], self.keypoints[..., 1]
        with np.errstate(invalid="ignore"):
            out = ((x < -IMAGE_MARGIN * w) | (x > (1 + IMAGE_MARGIN) * w)
                   | (y < -IMAGE_MARGIN * h) | (y > (1 + IMAGE_MARGIN) * h))
        if out.any():
            f, p, j = (int(v) for v in np.argwhere(out)[0])
            raise self._error(
                f"keypoint {self.skeleton.joint_names[j]} of person {p} at "
                f"({x[f, p, j]:.1f}, {y[f, p, j]:.1f}) lies far outside the {w}x{h} image: "
                "the image size contradicts the coordinates", frame=f, field="image_size")

    # -- shape ------------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.keypoints.shape[0])

    @property
    def n_persons(self) -> int:
        return int(self.keypoints.shape[1])

    @property
    def n_joints(self) -> int:
        return int(self.keypoints.shape[2])

    @property
    def n_detections(self) -> int:
        """Number of (frame, person) slots with at least one joint."""
        return int(np.isfinite(self.keypoints[..., 0]).any(-1).sum())

    # -- derived views ----------------------------------------------------------------------
    def canonical(self) -> NDArray[np.float64]:
        """Keypoints in the canonical layout, shape (n_frames, n_persons, 26, 3), read-only.

        Made once per Tracks: stages I, II, IV and V all start from it (0.1 s for 3000 frames
        of 5 persons each time).
        """
        cached = self.__dict__.get("_canonical")
        if cached is None:
            cached = to_canonical(self.keypoints, self.skeleton)
            cached.flags.writeable = False
            object.__setattr__(self, "_canonical", cached)
        return cached

    def joint(self, name: str) -> NDArray[np.float64]:
        """One canonical joint, shape (n_frames, n_persons, 3); NaN where missing or unmapped."""
        return self.canonical()[..., CANONICAL_INDEX[name], :]

    def frame_rate(self) -> float | None:
        """Frames per second: the given ``fps``, else one over the timestamps' median frame
        interval; None when neither is known."""
        if self.fps is not None:
            return float(self.fps)
        if self.timestamps is not None:
            d = np.diff(self.timestamps[np.isfinite(self.timestamps)])
            if d.size and np.median(d) > 0:
                return float(1.0 / np.median(d))
        return None

    def frame_times(self) -> NDArray[np.float64]:
        """Time of each frame in seconds: the timestamps when known, else ``f / fps``.

        Raises
        ------
        InputError
            If neither timestamps nor a frame rate are known.
        """
        if self.timestamps is not None:
            return self.timestamps - np.nanmin(self.timestamps)
        if self.fps is None:
            raise self._error("frame rate unknown: give --fps", field="fps")
        return np.arange(self.n_frames, dtype=np.float64) / self.fps

    def with_(self, **changes: Any) -> Tracks:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)

    def require_image_size(self) -> tuple[int, int]:
        """The image size, or a clear error telling how to supply it."""
        if self.image_size is None:
            raise self._error(
                "image size unknown: this format does not store it; give --image-size WxH "
                f"or --image-size {self.camera}=WxH", field="image_size")
        return self.image_size

    def __repr__(self) -> str:
        size = "x".join(map(str, self.image_size)) if self.image_size else "?"
        return (f"Tracks(camera={self.camera!r}, frames={self.n_frames}, persons={self.n_persons}"
                f", skeleton={self.skeleton.name}, image={size}, fps={self.fps})")


def stack_persons(frames: list[list[NDArray[np.float64]]], n_joints: int,
                  ids: list[list[int]] | None = None
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    """Pack a ragged list (per frame, per person, a (n_joints, 3) array) into a dense array.

    Returns
    -------
    keypoints : ndarray, shape (n_frames, max_persons, n_joints, 3)
        NaN-padded.
    track_ids : ndarray, shape (n_frames, max_persons), or None
        -1 padded; None when ``ids`` is None or holds no id at all.
    """
    n_p = max((len(p) for p in frames), default=0)
    kp = np.full((len(frames), max(n_p, 1), n_joints, 3), np.nan)
    tid = np.full((len(frames), max(n_p, 1)), -1, dtype=np.int64)
    for f, persons in enumerate(frames):
        for p, arr in enumerate(persons):
            kp[f, p] = arr
            if ids is not None:
                tid[f, p] = ids[f][p]
    has_ids = ids is not None and bool((tid >= 0).any())
    return kp, (tid if has_ids else None)
