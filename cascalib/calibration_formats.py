"""The calibration file formats: one registry for the library, the CLI, the REST API and docs.

Each :class:`CalibrationFormat` says where its writer and reader live, what it writes into an
output folder and how that is served. ``save_calibration`` / ``load_calibration``
(:mod:`cascalib.formats.calibration`), ``CalibrationResult.save``, ``cascalib calibrate
--formats``, ``cascalib convert``, ``api_schemas.RESULT_FORMATS`` and the service's
``/v1/jobs/{id}/result?format=`` all read this table; ``docs/formats.md`` is checked against it.

This module imports no reader or writer (the modules load on use), so the REST schemas can read
it without the numerical stack.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType

__all__ = ["CalibrationFormat", "FORMATS", "WRITABLE", "get_format"]


@dataclass(frozen=True)
class CalibrationFormat:
    """One calibration file format.

    Attributes
    ----------
    name : str
        The name ``--formats``, ``format=`` and ``?format=`` take.
    module : str
        Module under ``cascalib.formats.calibration`` with ``read`` (and ``write``).
    output : str or None
        What ``CalibrationResult.save`` writes in its folder: a file name, or a folder name
        ending in ``/`` (several files); None for a format cascalib only reads.
    media_type : str
        Media type of the file; a folder is served as a zip of its files.
    description : str
        The format in a few words (who reads it).
    """

    name: str
    module: str
    output: str | None
    media_type: str
    description: str

    @property
    def writable(self) -> bool:
        """Whether cascalib writes this format."""
        return self.output is not None

    @property
    def is_folder(self) -> bool:
        """Whether the format is a folder of files (served as a zip)."""
        return self.output is not None and self.output.endswith("/")

    @property
    def output_name(self) -> str:
        """The file or folder name in an output folder (no trailing ``/``)."""
        if self.output is None:
            raise ValueError(f"format {self.name!r} is read-only")
        return self.output.rstrip("/")

    @property
    def served_media_type(self) -> str:
        """Media type of a download: the file's, or ``application/zip`` for a folder."""
        return "application/zip" if self.is_folder else self.media_type

    def load(self) -> ModuleType:
        """The reader/writer module (imported on first use)."""
        return importlib.import_module(f"cascalib.formats.calibration.{self.module}")


_ALL = (
    CalibrationFormat("json", "native_json", "calibration.json", "application/json",
                      "cascalib's native JSON (with the clocks and the quality report)"),
    CalibrationFormat("toml", "anipose_toml", "calibration.toml", "application/toml",
                      "aniposelib / Pose2Sim TOML"),
    CalibrationFormat("caliscope", "caliscope_toml", "camera_array.toml", "application/toml",
                      "caliscope's camera_array.toml"),
    CalibrationFormat("opencv", "opencv_yaml", "calibration_opencv.yml", "application/yaml",
                      "one OpenCV FileStorage YAML file"),
    CalibrationFormat("colmap", "colmap_text", "colmap/", "text/plain",
                      "COLMAP text model (cameras.txt, images.txt, points3D.txt)"),
    CalibrationFormat("easymocap", "easymocap_yaml", "easymocap/", "application/yaml",
                      "EasyMocap intri.yml + extri.yml"),
    CalibrationFormat("qualisys", "qualisys_qca", None, "application/xml",
                      "Qualisys .qca.txt (XML)"),
)

#: Every format by name, in the order the CLI and the docs list them.
FORMATS: dict[str, CalibrationFormat] = {f.name: f for f in _ALL}

#: The formats cascalib writes (``--formats``, the REST result formats).
WRITABLE: tuple[str, ...] = tuple(f.name for f in _ALL if f.writable)


def get_format(name: str) -> CalibrationFormat:
    """The format called ``name`` (KeyError for an unknown one)."""
    return FORMATS[name]
