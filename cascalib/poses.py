"""3D poses: the triangulated joints of every person over time, and their file formats.

Axes: ``joints[t, p, j, c]`` with ``t`` the time sample (reference-camera frame
``reference_frames[t]``), ``p`` the person (``person_ids[t, p]`` links a person over time,
``-1`` where unknown), ``j`` the canonical joint (:data:`cascalib.skeletons.CANONICAL_JOINTS`)
and ``c`` in (x, y, z) world metres (z up, ground z = 0). NaN where not reconstructed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.skeletons import CANONICAL_JOINTS

__all__ = ["Poses3D", "load_poses"]

# OpenSim is y-up: (x, y, z)_opensim = (x, z, -y)_cascalib, a rotation of -90 deg about x.
_OPENSIM_FROM_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class Poses3D:
    """Triangulated 3D joints.

    Parameters
    ----------
    joints : ndarray, shape (T, P, 26, 3)
        World coordinates in metres, NaN where missing.
    reference_frames : ndarray, shape (T,)
        Reference-camera frame of each time sample.
    fps : float
        Frame rate of the reference camera (time = reference_frames / fps).
    person_ids : ndarray of int, shape (T, P)
        Identity of each person slot over time, -1 where unknown.
    residuals : ndarray, shape (T, P, 26), optional
        Mean reprojection error (px) of each triangulated joint.
    """

    joints: NDArray[np.float64]
    reference_frames: NDArray[np.float64]
    fps: float
    person_ids: NDArray[np.int64]
    residuals: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        j = np.asarray(self.joints, dtype=np.float64)
        if j.ndim != 4 or j.shape[2:] != (len(CANONICAL_JOINTS), 3):
            raise ValueError(f"joints must be (T, P, {len(CANONICAL_JOINTS)}, 3), got {j.shape}")
        object.__setattr__(self, "joints", j)
        object.__setattr__(self, "reference_frames",
                           np.asarray(self.reference_frames, dtype=np.float64))
        object.__setattr__(self, "person_ids", np.asarray(self.person_ids, dtype=np.int64))

    @property
    def times(self) -> NDArray[np.float64]:
        """Seconds since reference frame 0."""
        return self.reference_frames / self.fps

    def person_tracks(self) -> dict[int, NDArray[np.float64]]:
        """Per linked person id, its joints over all time samples, shape (T, 26, 3)."""
        out: dict[int, NDArray[np.float64]] = {}
        for pid in np.unique(self.person_ids[self.person_ids >= 0]):
            arr = np.full((len(self.joints), len(CANONICAL_JOINTS), 3), np.nan)
            t, p = np.nonzero(self.person_ids == pid)
            arr[t] = self.joints[t, p]
            out[int(pid)] = arr
        return out

    # -- writers ------------------------------------------------------------------------------
    def save(self, outdir: str | Path, formats: tuple[str, ...] = ("npz", "json", "trc")
             ) -> list[Path]:
        """Write the poses as ``poses.npz``, ``poses.json``, ``poses_person<N>.trc`` and
        ``poses_person<N>.c3d`` (C3D only when the optional ``ezc3d`` package is installed)."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        written: list[Path] = []
        if "npz" in formats:
            path = outdir / "poses.npz"
            np.savez_compressed(path, joints=self.joints, reference_frames=self.reference_frames,
                                fps=self.fps, person_ids=self.person_ids,
                                joint_names=np.array(CANONICAL_JOINTS),
                                **({} if self.residuals is None else
                                   {"residuals": self.residuals}))
            written.append(path)
        if "json" in formats:
            path = outdir / "poses.json"
            path.write_text(json.dumps(self.to_dict()))
            written.append(path)
        if "trc" in formats:
            written += [self._write_trc(outdir / f"poses_person{pid}.trc", arr)
                        for pid, arr in self.person_tracks().items()]
        if "c3d" in formats:
            written += self._write_c3d(outdir)
        return written

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form: null where missing."""
        def clean(a: NDArray[np.float64]) -> object:
            return [[None if not np.isfinite(v) else round(float(v), 5) for v in row]
                    for row in a.reshape(-1, a.shape[-1])]

        return {
            "schema": "cascalib/poses@1", "units": "m", "world": "z-up, ground z=0",
            "fps": self.fps, "joint_names": list(CANONICAL_JOINTS),
            "frames": [
                {"reference_frame": float(f),
                 "persons": [{"id": int(self.person_ids[t, p]), "joints": clean(self.joints[t, p])}
                             for p in range(self.joints.shape[1])
                             if np.isfinite(self.joints[t, p]).any()]}
                for t, f in enumerate(self.reference_frames)
            ],
        }

    def _write_trc(self, path: Path, joints: NDArray[np.float64]) -> Path:
        """OpenSim TRC (y-up, metres), one file per person."""
        n_t, n_j = joints.shape[:2]
        xyz = joints @ _OPENSIM_FROM_WORLD.T
        lines = [
            f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
            "OrigDataStartFrame\tOrigNumFrames",
            f"{self.fps:g}\t{self.fps:g}\t{n_t}\t{n_j}\tm\t{self.fps:g}\t1\t{n_t}",
            "Frame#\tTime\t" + "\t\t\t".join(CANONICAL_JOINTS) + "\t\t",
            "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(n_j)),
            "",
        ]
        for t in range(n_t):
            vals = "\t".join("" if not np.isfinite(v) else f"{v:.6f}" for v in xyz[t].ravel())
            lines.append(f"{t + 1}\t{self.times[t]:.6f}\t{vals}")
        path.write_text("\n".join(lines) + "\n")
        return path

    def _write_c3d(self, outdir: Path) -> list[Path]:
        try:
            import ezc3d
        except ImportError:
            return []
        written = []
        for pid, arr in self.person_tracks().items():
            c3d = ezc3d.c3d()
            c3d["parameters"]["POINT"]["RATE"]["value"] = [self.fps]
            c3d["parameters"]["POINT"]["LABELS"]["value"] = list(CANONICAL_JOINTS)
            c3d["parameters"]["POINT"]["UNITS"]["value"] = ["m"]
            pts = np.ones((4, arr.shape[1], arr.shape[0]))
            pts[:3] = np.transpose(arr, (2, 1, 0))
            c3d["data"]["points"] = pts
            path = outdir / f"poses_person{pid}.c3d"
            c3d.write(str(path))
            written.append(path)
        return written


def load_poses(path: str | Path) -> Poses3D:
    """Read ``poses.npz`` written by :meth:`Poses3D.save`."""
    path = Path(path)
    try:
        with np.load(path) as z:
            return Poses3D(z["joints"], z["reference_frames"], float(z["fps"]), z["person_ids"],
                           z["residuals"] if "residuals" in z else None)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"not a cascalib poses file: {exc}", file=str(path)) from None
