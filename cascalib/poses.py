"""3D poses: the triangulated joints of every person over time, and their file formats.

Axes: ``joints[t, p, j, c]`` with ``t`` the time sample (reference-camera frame
``reference_frames[t]``), ``p`` the slot (``person_ids[t, p]``: the reconstruction's track,
``-1`` where unknown; ``linked_ids[t, p]``: the person, the tracks of one person linked across
gaps and crossings by :func:`cascalib.linking.link_persons`), ``j`` the canonical joint
(:data:`cascalib.skeletons.CANONICAL_JOINTS`) and ``c`` in (x, y, z) world metres (z up, ground
z = 0). NaN where not reconstructed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.skeletons import CANONICAL_JOINTS
from cascalib.trc import write_trc

__all__ = ["Poses3D", "load_poses", "POSE_FORMATS"]

#: Every pose file kind :meth:`Poses3D.save` writes (C3D only when ``ezc3d`` is installed).
POSE_FORMATS = ("npz", "json", "trc", "c3d")


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
        Track of each person slot over time, -1 where unknown.
    residuals : ndarray, shape (T, P, 26), optional
        Mean reprojection error (px) of each triangulated joint.
    linked_ids : ndarray of int, shape (T, P), optional
        Person of each slot, the tracks of one person linked; -1 where none. Default: linked
        from the tracks (:func:`cascalib.linking.link_persons`) when first needed.
    """

    joints: NDArray[np.float64]
    reference_frames: NDArray[np.float64]
    fps: float
    person_ids: NDArray[np.int64]
    residuals: NDArray[np.float64] | None = None
    linked_ids: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        j = np.asarray(self.joints, dtype=np.float64)
        if j.ndim != 4 or j.shape[2:] != (len(CANONICAL_JOINTS), 3):
            raise ValueError(f"joints must be (T, P, {len(CANONICAL_JOINTS)}, 3), got {j.shape}")
        object.__setattr__(self, "joints", j)
        object.__setattr__(self, "reference_frames",
                           np.asarray(self.reference_frames, dtype=np.float64))
        object.__setattr__(self, "person_ids", np.asarray(self.person_ids, dtype=np.int64))
        if self.linked_ids is not None:
            object.__setattr__(self, "linked_ids", np.asarray(self.linked_ids, dtype=np.int64))

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

    def persons(self) -> dict[int, tuple[NDArray[np.int64], NDArray[np.int64]]]:
        """Per linked person, the time samples where it is seen and its slot there."""
        if self.linked_ids is None:
            from cascalib.linking import link_persons

            object.__setattr__(self, "linked_ids",
                               link_persons(self.joints, self.person_ids, self.times))
        assert self.linked_ids is not None
        t, p = np.nonzero(self.linked_ids >= 0)
        ids = self.linked_ids[t, p]
        return {int(k): (t[ids == k], p[ids == k]) for k in np.unique(ids)}

    # -- writers ------------------------------------------------------------------------------
    def save(self, outdir: str | Path, formats: tuple[str, ...] = POSE_FORMATS) -> list[Path]:
        """Write the poses as ``poses.npz`` (every array), ``poses.json``, and per linked
        person ``poses_person<N>.trc`` (OpenSim) and ``poses_person<N>.c3d`` (only when the
        optional ``ezc3d`` package is installed); return the files written."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        persons = self.persons()
        written: list[Path] = []
        if "npz" in formats:
            written.append(self._write_npz(outdir / "poses.npz"))
        if "json" in formats:
            written.append(write_json(self, outdir / "poses.json"))
        seen = np.asarray(np.isfinite(self.joints[..., 0]).any(axis=(0, 1)))  # joints ever seen
        names = [n for n, s in zip(CANONICAL_JOINTS, seen, strict=True) if s]
        for pid, (t, p) in persons.items():
            joints = self.joints[t, p][:, seen]
            if "trc" in formats:
                written.append(write_trc(outdir / f"poses_person{pid}.trc", joints,
                                         np.rint(self.reference_frames[t]).astype(int) + 1,
                                         self.times[t], names, self.fps))
            if "c3d" in formats:
                written += _write_c3d(outdir / f"poses_person{pid}.c3d", joints, names,
                                      self.fps)
        return written

    def _write_npz(self, path: Path) -> Path:
        """Every array, uncompressed: deflating them took most of the time of writing."""
        assert self.linked_ids is not None
        np.savez(path, joints=self.joints, reference_frames=self.reference_frames,
                 fps=self.fps, person_ids=self.person_ids, linked_person_ids=self.linked_ids,
                 joint_names=np.array(CANONICAL_JOINTS),
                 **({} if self.residuals is None else {"residuals": self.residuals}))  # type: ignore[arg-type]
        return path


def write_json(poses: Poses3D, path: Path) -> Path:
    """``poses.json`` (schema ``cascalib/poses@1``): per reference frame the persons seen, each
    with its track ``id``, its linked ``person`` (-1: none) and 26 joints (null where missing).

    Written as one formatted string (numbers with 5 decimals): building the nested lists
    value by value took seconds for a long recording."""
    seen = np.asarray(np.isfinite(poses.joints[..., 0]).any(-1))  # (T, P)
    linked = poses.linked_ids if poses.linked_ids is not None else np.full(seen.shape, -1)
    joint = "[%.5f,%.5f,%.5f]"
    person = '{"id":%d,"person":%d,"joints":[' + ",".join([joint] * len(CANONICAL_JOINTS)) + "]}"
    frames = []
    for t, f in enumerate(poses.reference_frames.tolist()):
        p = np.flatnonzero(seen[t])
        vals = np.column_stack([poses.person_ids[t, p], linked[t, p], poses.joints[t, p].reshape(
            len(p), 3 * len(CANONICAL_JOINTS))]).ravel().tolist()
        frames.append(f'{{"reference_frame":{f!r},"persons":['
                      + ",".join([person] * len(p)) % tuple(vals) + "]}")
    head = ('{"schema":"cascalib/poses@1","units":"m","world":"z-up, ground z=0","fps":%r,'  # noqa: UP031
            '"joint_names":[%s],"frames":[' % (float(poses.fps),
                                               ",".join(f'"{n}"' for n in CANONICAL_JOINTS)))
    path.write_text((head + ",".join(frames) + "]}").replace("nan", "null"))
    return path


def _write_c3d(path: Path, joints: NDArray[np.float64], names: list[str], fps: float
               ) -> list[Path]:
    """One person's markers (N, M, 3) as C3D (z-up metres), when ``ezc3d`` is installed."""
    try:
        import ezc3d
    except ImportError:
        return []
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["m"]
    pts = np.ones((4, joints.shape[1], joints.shape[0]))
    pts[:3] = np.transpose(joints, (2, 1, 0))
    c3d["data"]["points"] = pts
    c3d.write(str(path))
    return [path]


def load_poses(path: str | Path) -> Poses3D:
    """Read ``poses.npz`` written by :meth:`Poses3D.save`."""
    path = Path(path)
    try:
        with np.load(path) as z:
            return Poses3D(z["joints"], z["reference_frames"], float(z["fps"]), z["person_ids"],
                           z["residuals"] if "residuals" in z else None,
                           z["linked_person_ids"] if "linked_person_ids" in z else None)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"not a cascalib poses file: {exc}", file=str(path)) from None
