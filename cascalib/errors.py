"""Exception hierarchy of cascalib.

Every error a user can cause names *where* the problem is: the file, the camera, the frame and
the field, so that a message such as ``cam2.json: camera 'cam2', frame 17, field 'keypoints':
expected 17 joints, got 12`` can be acted on without reading the code.
"""

from __future__ import annotations

__all__ = [
    "CascalibError",
    "InputError",
    "CalibrationFileError",
    "EstimationFailed",
    "RefinementFailed",
]


class CascalibError(Exception):
    """Base class of every error cascalib raises on purpose.

    Parameters
    ----------
    message : str
        What is wrong, in words a user understands.
    file : str, optional
        The file (or folder) the problem was found in.
    camera : str, optional
        The camera concerned.
    frame : int, optional
        The frame index concerned (0-based, as stored in the input).
    field : str, optional
        The field, key or column concerned.
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        camera: str | None = None,
        frame: int | None = None,
        field: str | None = None,
    ) -> None:
        self.message = message
        self.file = None if file is None else str(file)
        self.camera = camera
        self.frame = frame
        self.field = field
        super().__init__(self._format())

    def _format(self) -> str:
        where = []
        if self.file is not None:
            where.append(f"file '{self.file}'")
        if self.camera is not None:
            where.append(f"camera '{self.camera}'")
        if self.frame is not None:
            where.append(f"frame {self.frame}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        return f"{', '.join(where)}: {self.message}" if where else self.message

    def to_dict(self) -> dict[str, object]:
        """Machine-readable form (used by the CLI's ``--json`` and the service's problem bodies)."""
        return {
            "type": type(self).__name__,
            "message": self.message,
            "file": self.file,
            "camera": self.camera,
            "frame": self.frame,
            "field": self.field,
        }


class InputError(CascalibError, ValueError):
    """Keypoint input that cannot be used: unparseable, inconsistent or out of range."""


class CalibrationFileError(CascalibError, ValueError):
    """A calibration file that cannot be read or does not describe valid cameras."""


class EstimationFailed(CascalibError, RuntimeError):
    """A stage of the cascade could not produce a trustworthy estimate (degenerate geometry,
    too few usable detections, ...). The message says why and what would help."""


class RefinementFailed(CascalibError, RuntimeError):
    """The joint refinement (GTSAM) failed numerically or did not converge."""
