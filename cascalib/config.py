"""The one configuration of a calibration run: every parameter, documented and defaulted.

Top-level fields are the facts a user knows about the session (person height, synchronised
cameras, known intrinsics, reference camera, seed); one nested section per stage holds the
algorithm's parameters (defaults: the paper's values where it gives them, see each field).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

from cascalib.stages.align_config import AlignConfig
from cascalib.stages.refine_config import RefineConfig
from cascalib.stages.single_view import SingleViewConfig

__all__ = ["CalibrationConfig", "KnownIntrinsics"]


class KnownIntrinsics(BaseModel):
    """Intrinsics of one camera measured beforehand (e.g. with a checkerboard)."""

    model_config = ConfigDict(extra="forbid")

    K: list[list[float]] = Field(description="3x3 intrinsic matrix (pixels).")
    dist: list[float] = Field(default_factory=lambda: [0.0] * 5,
                              description="OpenCV distortion k1 k2 p1 p2 k3.")

    @field_validator("K")
    @classmethod
    def _check_k(cls, v: list[list[float]]) -> list[list[float]]:
        if len(v) != 3 or any(len(r) != 3 for r in v) or v[0][0] <= 0 or v[1][1] <= 0:
            raise ValueError("K must be a 3x3 matrix with positive focal lengths")
        return v


class CalibrationConfig(BaseModel):
    """Every parameter of :func:`cascalib.calibrate`."""

    model_config = ConfigDict(extra="forbid")

    height: float = Field(
        1.70, gt=0.5, lt=2.5,
        description="Mean standing height of the people (m): sets the metric scale. The paper "
                    "uses one assumed height for everyone.")
    seed: int = Field(0, description="Seed of every random choice (RANSAC, subsampling).")
    synchronized: bool = Field(
        False, description="The cameras are already synchronised (hardware sync or same clock):"
                           " time offsets are 0 and rates follow the frame rates; only the "
                           "geometry is estimated.")
    reference_camera: str | None = Field(
        None, description="Camera whose clock and ground frame define the world (default: the "
                          "first).")
    known_intrinsics: dict[str, KnownIntrinsics] = Field(
        default_factory=dict,
        description="Cameras whose intrinsics are known: their focal, principal point and "
                    "distortion are kept as given.")
    single_view: SingleViewConfig = Field(default_factory=SingleViewConfig,
                                          description="Stage I: focal length and ground plane.")
    align: AlignConfig = Field(default_factory=AlignConfig,
                               description="Stages II-IV: synchronisation and ground alignment.")
    refine: RefineConfig = Field(default_factory=RefineConfig,
                                 description="Stage V: GTSAM bundle adjustment.")

    @classmethod
    def from_file(cls, path: str | Path) -> CalibrationConfig:
        """Load from a JSON or TOML file (the same keys as the model)."""
        import json
        import tomllib

        p = Path(path)
        text = p.read_text()
        data = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
        return cls.model_validate(data)
