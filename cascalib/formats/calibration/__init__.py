"""Calibration files: read and write a :class:`~cascalib.calibration.Calibration`.

==============  ===========================================  ======  ======  ==================
format          files                                        read    write   keeps time/fps
==============  ===========================================  ======  ======  ==================
``json``        cascalib ``calibration.json`` (native)       yes     yes     yes (+ quality)
``toml``        aniposelib / Pose2Sim ``.toml``              yes     yes     yes (extra keys)
                (also caliscope's older ``config.toml``)
``caliscope``   caliscope ``camera_array.toml``              yes     yes     yes (extra keys)
``opencv``      one OpenCV FileStorage ``.yml/.yaml/.xml``   yes     yes     yes
``colmap``      folder: cameras.txt, images.txt, points3D    yes     yes     sidecar file
``easymocap``   folder: intri.yml, extri.yml                 yes     yes     sidecar file
``qualisys``    Qualisys ``.qca.txt`` (XML)                  yes     no      no
==============  ===========================================  ======  ======  ==================

The names, output file names and modules come from the one registry,
:mod:`cascalib.calibration_formats`.

Each format module has ``to_dict``/``from_dict`` (a plain-dict round trip, as aniposelib's
``get_dict``/``from_dict``) and ``read``/``write``. Every reader validates through one helper and
raises :class:`~cascalib.errors.CalibrationFileError` naming the file, camera and field.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType

from cascalib import calibration_formats
from cascalib.calibration import Calibration
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration import anipose_toml, caliscope_toml, easymocap_yaml
from cascalib.formats.calibration._time_sidecar import TIME_SIDECAR

__all__ = ["FORMATS", "TIME_SIDECAR", "detect_format", "load_calibration", "save_calibration"]

#: Format name -> module with ``read`` (and ``write`` unless read-only), from the registry.
FORMATS: dict[str, ModuleType] = {name: f.load()
                                  for name, f in calibration_formats.FORMATS.items()}
_ALIASES = {"native": "json", "aniposelib": "toml", "anipose": "toml", "pose2sim": "toml",
            "yaml": "opencv", "yml": "opencv", "xml": "opencv", "qca": "qualisys"}


def _canonical(fmt: str, *, file: str | None) -> str:
    name = _ALIASES.get(fmt.lower(), fmt.lower())
    if name not in FORMATS:
        raise CalibrationFileError(
            f"unknown calibration format {fmt!r}; known: {', '.join(FORMATS)} "
            f"(aliases: {', '.join(_ALIASES)})", file=file, field="format")
    return name


def detect_format(path: str | Path) -> str:
    """Format of a calibration file or folder, from its name and, if needed, its content."""
    path = Path(path)
    if path.is_dir():
        if (path / "cameras.txt").is_file() and (path / "images.txt").is_file():
            return "colmap"
        if (path / easymocap_yaml.INTRI).is_file() and (path / easymocap_yaml.EXTRI).is_file():
            return "easymocap"
        if (path / "calibration.json").is_file():
            return "json"
        raise CalibrationFileError("folder holds no known calibration (COLMAP cameras.txt + "
                                   "images.txt, EasyMocap intri.yml + extri.yml or "
                                   "calibration.json)", file=str(path))
    name = path.name.lower()
    if name in ("cameras.txt", "images.txt", "points3d.txt"):
        return "colmap"
    if name in (easymocap_yaml.INTRI, easymocap_yaml.EXTRI):
        return "easymocap"
    if name.endswith(".qca.txt") or name.endswith(".qca"):
        return "qualisys"
    if path.suffix.lower() == ".toml":
        return _toml_layout(path)
    by_suffix = {".json": "json", ".yml": "opencv", ".yaml": "opencv", ".xml": "opencv"}
    if path.suffix.lower() in by_suffix:
        return by_suffix[path.suffix.lower()]
    return _sniff(path)


def _toml_layout(path: Path) -> str:
    """``caliscope`` for a ``[cameras.<id>]`` layout, else ``toml`` (its reader reports errors)."""
    try:
        data = anipose_toml.load_toml(path)
    except (OSError, CalibrationFileError):
        return "toml"
    return "caliscope" if caliscope_toml.is_camera_array(data) else "toml"


def _sniff(path: Path) -> str:
    try:
        head = path.read_text(encoding="utf-8", errors="replace")[:2000].lstrip()
    except OSError as exc:
        raise CalibrationFileError(f"cannot read: {exc.strerror}", file=str(path)) from None
    if head.startswith("{"):
        return "json"
    if "<calibration" in head:
        return "qualisys"
    if head.startswith("%YAML") or head.startswith("<?xml"):
        return "opencv"
    if "[cameras." in head:
        return "caliscope"
    if "[cam" in head or "matrix" in head:
        return "toml"
    raise CalibrationFileError("cannot tell the calibration format from the name or content; "
                               "pass format=", file=str(path), field="format")


def load_calibration(path: str | Path, format: str | None = None) -> Calibration:
    """Read a calibration in any supported format.

    Parameters
    ----------
    path : str or Path
        File, or folder for ``colmap`` and ``easymocap``.
    format : str, optional
        One of :data:`FORMATS` (or an alias such as ``"pose2sim"``); detected when omitted.

    Raises
    ------
    CalibrationFileError
        Unknown format, missing file, or invalid content (naming file, camera and field).
    """
    path = Path(path)
    if not path.exists():
        raise CalibrationFileError("file not found", file=str(path))
    fmt = _canonical(format, file=str(path)) if format else detect_format(path)
    return FORMATS[fmt].read(path)  # type: ignore[no-any-return]


def save_calibration(calib: Calibration, path: str | Path, format: str = "json") -> list[Path]:
    """Write ``calib``; returns the files written.

    ``path`` is a file for ``json``, ``toml`` and ``opencv`` and a folder for ``colmap`` and
    ``easymocap``. What each format cannot hold is listed in the module table.
    """
    fmt = _canonical(format, file=str(path))
    writer: Callable[[Calibration, Path], list[Path]] | None = getattr(FORMATS[fmt], "write",
                                                                      None)
    if writer is None:
        raise CalibrationFileError(f"format {fmt!r} can be read but not written",
                                   file=str(path), field="format")
    return writer(calib, Path(path))
