"""Simulated multi-camera scenes: configuration, :func:`simulate` and the :class:`Scene` it returns.

A scene is people walking (and sometimes bending, sitting ...) on the ground plane z = 0 of a
z-up world, filmed by unsynchronised cameras and seen through a simulated 2D pose detector. The
same seed always gives the same scene; the people, the rig, the clocks and each camera's detector
draw from independent random streams, so changing e.g. the detector settings keeps the people
and the cameras.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import InputError
from cascalib.simulate.detector import DetectorConfig, detect
from cascalib.simulate.people import PeopleConfig, Person, make_people
from cascalib.simulate.rigs import RigConfig, make_rig
from cascalib.simulate.timing import Clock, TimingConfig, make_clocks
from cascalib.skeletons import get_skeleton
from cascalib.tracks import Tracks

__all__ = ["SceneConfig", "Scene", "simulate"]

logger = logging.getLogger(__name__)


class SceneConfig(BaseModel):
    """Everything that defines a simulated scene (together with the seed)."""

    model_config = ConfigDict(extra="forbid")

    description: str = Field(default="", description="One line saying what the scene is for.")
    duration_s: float = Field(default=60.0, gt=2.0, le=3600, description="Length of the scene (s).")
    people: PeopleConfig = Field(default_factory=PeopleConfig, description="The persons.")
    rig: RigConfig = Field(default_factory=RigConfig, description="The cameras.")
    timing: TimingConfig = Field(default_factory=TimingConfig, description="Camera clocks.")
    detector: DetectorConfig = Field(
        default_factory=DetectorConfig, description="The simulated 2D pose detector.")
    skeleton: str = Field(default="halpe26", description="Skeleton of the written detections.")
    camera_names: list[str] | None = Field(
        default=None, description="Camera names (default cam0, cam1, ...).")

    @model_validator(mode="after")
    def _check_names(self) -> SceneConfig:
        names = self.camera_names
        if names is not None and (len(names) != self.rig.n_cameras
                                  or len(set(names)) != len(names)):
            raise ValueError(f"camera_names must be {self.rig.n_cameras} unique names, "
                             f"got {names}")
        return self

    def with_(self, **changes: Any) -> SceneConfig:
        """A copy with (dotted, nested) fields replaced: ``with_(**{"people.n_persons": 3})``."""
        data = self.model_dump()
        for key, value in changes.items():
            node = data
            *parents, leaf = key.split(".")
            for p in parents:
                node = node[p]
            node[leaf] = value.model_dump() if isinstance(value, BaseModel) else value
        return SceneConfig.model_validate(data)


@dataclass(eq=False)
class Scene:
    """A simulated scene: true cameras, people and the detections each camera made.

    Attributes
    ----------
    config : SceneConfig
    seed : int
    people : list of Person
        The simulated persons (their motion can be sampled at any time).
    clocks : list of Clock
        One per camera, in camera order.
    truth : Calibration
        True cameras (world z-up, ground z = 0) with fps, time_offset and time_rate.
    tracks : list of Tracks
        Detections, one per camera, in the configured skeleton.
    """

    config: SceneConfig
    seed: int
    people: list[Person]
    clocks: list[Clock]
    truth: Calibration
    tracks: list[Tracks]
    _slots: dict[str, NDArray[np.int64]] = field(repr=False)
    _joints: dict[str, NDArray[np.float64]] = field(default_factory=dict, repr=False)

    @property
    def heights(self) -> NDArray[np.float64]:
        """True person heights (m), shape (P,)."""
        return np.array([p.height for p in self.people])

    @property
    def ground_plane(self) -> tuple[NDArray[np.float64], float]:
        """Ground plane as (unit normal pointing up, offset): points x with ``n @ x = offset``."""
        return np.array([0.0, 0.0, 1.0]), 0.0

    @property
    def camera_names(self) -> list[str]:
        return self.truth.names

    def _index(self, camera: str) -> int:
        try:
            return self.truth.names.index(camera)
        except ValueError:
            raise KeyError(f"no camera {camera!r}; cameras: {self.truth.names}") from None

    def frame_times(self, camera: str) -> NDArray[np.float64]:
        """World time (s) of each frame of ``camera``, shape (F_c,)."""
        return self.clocks[self._index(camera)].frame_times()

    def joints3d(self, camera: str) -> NDArray[np.float64]:
        """True canonical 3D joints at the frames of ``camera``, shape (F_c, P, 26, 3)."""
        if camera not in self._joints:
            self._joints[camera] = joints_at(self.people, self.frame_times(camera))
        return self._joints[camera]

    def joints_at(self, times: NDArray[np.float64]) -> NDArray[np.float64]:
        """True canonical 3D joints at world times (s), shape (T, P, 26, 3)."""
        return joints_at(self.people, np.asarray(times, dtype=np.float64))

    def reference_times(self, frames: NDArray[np.float64]) -> NDArray[np.float64]:
        """World time (s) of (fractional) reference-camera frames, shape like ``frames``.

        ``scene.joints_at(scene.reference_times(r))`` are the true poses at reference frames
        ``r`` (e.g. to compare with stage V's poses per reference frame).
        """
        ref = self.clocks[0]
        return ref.start + np.asarray(frames, dtype=np.float64) * (1 + ref.drift) / ref.fps

    def slot_to_person(self, camera: str) -> NDArray[np.int64]:
        """True person of each detection slot of ``camera``, shape (F_c, S_c).

        ``>= 0`` the person index (into :attr:`heights` and the P axis of :meth:`joints3d`),
        -1 a false positive, -2 an empty slot.
        """
        self._index(camera)
        return self._slots[camera]

    def plane_camera(self, camera: str) -> tuple[Camera, NDArray[np.float64], NDArray[np.float64]]:
        """The true camera in its OWN plane frame, as stage I returns it (for testing stage II).

        The plane frame has z up (the ground normal), the camera centre at (0, 0, height) and
        the optical axis, projected on the ground, along +x.

        Returns
        -------
        camera : Camera
            The camera expressed in its plane frame (same intrinsics and clock).
        R, t : ndarray, shapes (3, 3) and (3,)
            ``world_from_plane``: ``x_world = R @ x_plane + t``.
        """
        cam = self.truth[camera]
        c = cam.center
        axis = cam.R[2]  # optical axis in world coordinates
        yaw = float(np.arctan2(axis[1], axis[0]))
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0],
                      [0.0, 0.0, 1.0]])
        t = np.array([c[0], c[1], 0.0])
        return cam.with_(R=cam.R @ R, t=cam.R @ t + cam.t), R, t

    def save(self, outdir: str | Path, format: str = "native-json") -> Path:
        """Write the detections and the ground truth to ``outdir``; returns ``outdir``.

        Writes ``tracks/<camera>.<ext>`` in ``format`` (any format of
        :func:`cascalib.formats.write_tracks`), ``calibration.json`` (the true cameras) and
        ``truth.npz`` (heights, ground plane, per camera the 3D joints, frame times and slot
        to person map).
        """
        from cascalib.simulate.output import save_scene

        return save_scene(self, Path(outdir), format)


def joints_at(people: list[Person], times: NDArray[np.float64]) -> NDArray[np.float64]:
    """Joints of all persons at world times ``times``, shape (T, P, 26, 3)."""
    return np.stack([p.joints(times) for p in people], axis=1)


def _streams(seed: int | np.random.SeedSequence, n_cameras: int) -> dict[str, Any]:
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    people, rig, timing, detector = ss.spawn(4)
    return {
        "people": np.random.default_rng(people),
        "rig": np.random.default_rng(rig),
        "timing": np.random.default_rng(timing),
        "detector": [np.random.default_rng(s) for s in detector.spawn(n_cameras)],
    }


def _to_skeleton(kp: NDArray[np.float64], skeleton: str) -> NDArray[np.float64]:
    """Canonical (..., 26, 3) keypoints in another skeleton's layout (unmapped joints NaN)."""
    sk = get_skeleton(skeleton)
    idx = sk.canonical_indices
    out = kp[..., np.maximum(idx, 0), :].copy()
    out[..., idx < 0, :] = np.nan
    return out


def simulate(config: SceneConfig | str = "terrace", seed: int = 0, **overrides: Any) -> Scene:
    """Simulate a scene.

    Parameters
    ----------
    config : SceneConfig or str
        A configuration or the name of a preset in :data:`cascalib.simulate.PRESETS`.
    seed : int
        Random seed; the same seed and configuration always give the same scene.
    **overrides
        Dotted field replacements applied to the configuration, e.g.
        ``simulate("terrace", **{"people.n_persons": 3})``.

    Returns
    -------
    Scene

    Raises
    ------
    InputError
        If a camera sees nobody in the whole scene (change the rig or the seed).
    """
    if isinstance(config, str):
        from cascalib.simulate.presets import preset

        config = preset(config)
    if overrides:
        config = config.with_(**overrides)
    rig_cfg = config.rig
    rng = _streams(seed, rig_cfg.n_cameras)
    people = make_people(config.people, config.duration_s, rng["people"])
    area = config.people.area
    cams = make_rig(rig_cfg, area, rng["rig"], config.camera_names)
    clocks = make_clocks(config.timing, len(cams), config.duration_s, rng["timing"])
    heights = np.array([p.height for p in people])
    truth_cams: list[Camera] = []
    tracks: list[Tracks] = []
    slots: dict[str, NDArray[np.int64]] = {}
    joints: dict[str, NDArray[np.float64]] = {}
    for cam, clock, drng in zip(cams, clocks, rng["detector"], strict=True):
        offset, rate = clock.time_offset_rate(clocks[0])
        cam = cam.with_(fps=clock.fps, time_offset=offset, time_rate=rate)
        truth_cams.append(cam)
        x3d = joints_at(people, clock.frame_times())
        joints[cam.name] = x3d
        det = detect(cam, x3d, heights, config.detector, drng)
        if not np.isfinite(det.keypoints[..., 0]).any():
            raise InputError("the simulated camera sees nobody; change the rig or the seed",
                             camera=cam.name)
        tracks.append(Tracks(cam.name, _to_skeleton(det.keypoints, config.skeleton),
                             get_skeleton(config.skeleton), image_size=cam.image_size,
                             fps=clock.fps, track_ids=det.track_ids,
                             meta={"simulated": True, "seed": seed}))
        slots[cam.name] = det.slot_to_person
    truth = Calibration(truth_cams, quality={"simulated": True, "seed": seed})
    logger.info("simulated %d cameras, %d persons, %.0f s", len(cams), len(people),
                config.duration_s)
    return Scene(config, seed, people, clocks, truth, tracks, slots, joints)
