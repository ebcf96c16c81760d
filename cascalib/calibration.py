"""A calibrated rig: the cameras of one session in one world frame and one clock."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError

__all__ = ["Calibration"]


@dataclass(eq=False)
class Calibration:
    """Cameras of one rig, in the order given (never re-sorted by name).

    Parameters
    ----------
    cameras : list of Camera
        The cameras; names must be unique.
    reference_camera : str, optional
        Camera whose clock (and, when the world is a camera frame, whose pose) defines the world;
        default: the first camera.
    quality : dict
        Free-form quality report (reprojection errors, verdicts ...), kept in ``calibration.json``.
    world : str
        Description of the world frame: ``"z-up, ground z=0"`` for cascalib's own results; other
        tools' files may use a camera frame.
    """

    cameras: list[Camera]
    reference_camera: str | None = None
    quality: dict[str, Any] = field(default_factory=dict)
    world: str = "z-up, ground z=0"

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        if not names:
            raise CalibrationFileError("a calibration needs at least one camera", field="cameras")
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise CalibrationFileError(f"duplicate camera names: {sorted(dup)}", field="cameras")
        if self.reference_camera is None:
            self.reference_camera = names[0]
        elif self.reference_camera not in names:
            raise CalibrationFileError(
                f"reference camera {self.reference_camera!r} is not one of {names}",
                field="reference_camera")

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def __getitem__(self, name: str) -> Camera:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:
        return any(c.name == name for c in self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __len__(self) -> int:
        return len(self.cameras)

    def subset(self, names: list[str]) -> Calibration:
        """The cameras ``names`` only (in this calibration's order).

        If the reference camera is left out, the first kept camera becomes the reference and
        every clock is re-expressed in its frames: frame ``k`` of camera ``c`` shows reference
        frame ``S_c k + O_c``, so in the frames of the new reference ``r`` it is
        ``(S_c / S_r) k + (O_c - O_r) / S_r``.
        """
        missing = [n for n in names if n not in self]
        if missing:
            raise CalibrationFileError(f"no camera(s) {missing} in the calibration "
                                       f"(cameras: {self.names})", field="cameras")
        kept = [c for c in self.cameras if c.name in names]
        reference = self.reference_camera
        if reference not in names and kept:
            r = kept[0]
            kept = [c.with_(time_offset=(c.time_offset - r.time_offset) / r.time_rate,
                            time_rate=c.time_rate / r.time_rate) for c in kept]
            reference = r.name
        return Calibration(kept, reference_camera=reference, quality=self.quality,
                           world=self.world)
