"""Plain-dict access to OpenCV FileStorage files (YAML/XML), used by the OpenCV and EasyMocap
formats: ``read_nodes(path) -> {key: value}`` and ``write_nodes(path, {key: value})``.

Values are ``str``, ``int``, ``float``, lists of strings (sequences) and float ndarrays
(``!!opencv-matrix``); FileStorage writes doubles with 17 significant digits, so numbers survive a
round trip exactly.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from cascalib.errors import CalibrationFileError

__all__ = ["read_nodes", "write_nodes"]


def _value(node: cv2.FileNode) -> Any:
    if node.isString():
        return node.string()
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isSeq():
        return [_value(node.at(i)) for i in range(node.size())]
    if node.isMap():
        keys = set(node.keys())
        if {"rows", "cols", "data"} <= keys:
            return np.asarray(node.mat(), dtype=np.float64)
        return {k: _value(node.getNode(k)) for k in node.keys()}
    return None


def read_nodes(path: str | Path) -> dict[str, Any]:
    """All top-level nodes of a FileStorage file, in file order."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationFileError("file not found", file=str(path))
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        # OpenCV 5's binding wraps the parser's cv2.error in a SystemError
        cause = exc if isinstance(exc, cv2.error) else exc.__cause__ or exc
        # OpenCV's message ends with "in function '<file>(<line>): <what>'"
        detail = str(getattr(cause, "msg", None) or cause).strip().rstrip("'")
        detail = detail.rsplit("): ", 1)[-1] if "): " in detail else detail
        line = re.search(r"\((\d+)\): ", str(getattr(cause, "msg", "")))
        if line:
            detail = f"line {line.group(1)}: {detail}"
        raise CalibrationFileError(f"OpenCV cannot parse this file: {detail}",
                                   file=str(path)) from None
    try:
        if not fs.isOpened():
            raise CalibrationFileError("OpenCV cannot open this file", file=str(path))
        root = fs.root()
        return {k: _value(root.getNode(k)) for k in root.keys()}
    finally:
        fs.release()


def write_nodes(path: str | Path, nodes: dict[str, Any]) -> Path:
    """Write top-level nodes (see module docstring for the value types) to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        for key, value in nodes.items():
            if isinstance(value, (list, tuple)):
                fs.startWriteStruct(key, cv2.FileNode_SEQ)
                for item in value:
                    fs.write("", item)
                fs.endWriteStruct()
            elif isinstance(value, np.ndarray):
                fs.write(key, np.asarray(value, dtype=np.float64))
            elif isinstance(value, bool):
                fs.write(key, int(value))
            elif isinstance(value, (int, float, str)):
                fs.write(key, value)
            else:
                raise TypeError(f"cannot write {type(value).__name__} to FileStorage ({key})")
    finally:
        fs.release()
    return path
