"""Calibration files on the real reference calibrations: exactness of every writer/reader round
trip and the agreement of the Qualisys reader with Pose2Sim's conversion of the same file.

Run: ``python bench/bench_calibration_files.py``. For each real calibration and each writable
format it prints the largest parameter change after write + read (K, dist, R, t), the largest
pixel change when projecting 1000 points seen by the camera, and the write + read time.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from cascalib import Calibration
from cascalib.formats import load_calibration, save_calibration
from cascalib.metrics import compare_calibrations

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data"
FILES = {"qualisys .qca.txt": REAL / "pose2sim_demo" / "Calib.qca.txt",
         "pose2sim toml": REAL / "pose2sim_demo" / "Calib_qualisys_converted_by_pose2sim.toml",
         "caliscope toml": REAL / "caliscope_4cam" / "config.toml"}
TARGETS = {"json": "c.json", "toml": "c.toml", "opencv": "c.yml", "colmap": "model",
           "easymocap": "emc"}


def visible_points(calib: Calibration, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """1000 points 1-5 m in front of each camera, inside its image."""
    out = {}
    for cam in calib:
        W, H = cam.image_size
        uv = rng.uniform([0, 0], [W - 1, H - 1], (1000, 2))
        out[cam.name] = cam.center + rng.uniform(1, 5, (1000, 1)) * cam.rays(uv)
    return out


def round_trip_row(calib: Calibration, fmt: str, tmp: Path, points: dict[str, np.ndarray]
                   ) -> list[str]:
    t0 = time.perf_counter()
    save_calibration(calib, tmp / TARGETS[fmt], format=fmt)
    back = load_calibration(tmp / TARGETS[fmt])
    elapsed = time.perf_counter() - t0
    param = max(float(np.abs(getattr(a, f) - getattr(b, f)).max())
                for a, b in zip(back, calib, strict=True) for f in ("K", "dist", "R", "t"))
    pixels = max(float(np.nanmax(np.abs(a.project(points[a.name]) - b.project(points[b.name]))))
                 for a, b in zip(back, calib, strict=True))
    return [fmt, f"{param:.1e}", f"{pixels:.1e}", f"{1000 * elapsed:.1f}"]


def print_table(header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w)
                        in enumerate(zip(r, widths, strict=True))))


def main() -> None:
    rng = np.random.default_rng(0)
    for label, path in FILES.items():
        calib = load_calibration(path)
        points = visible_points(calib, rng)
        with tempfile.TemporaryDirectory() as tmp:
            rows = [round_trip_row(calib, fmt, Path(tmp), points) for fmt in TARGETS]
        print(f"\n{label}: {path.name} ({len(calib)} cameras, world: {calib.world})")
        print_table(["format", "max |param| change", "max px change", "write+read ms"], rows)
    qca = load_calibration(FILES["qualisys .qca.txt"])
    toml = load_calibration(FILES["pose2sim toml"])
    print("\nQualisys reader vs Pose2Sim's TOML conversion of the same file:\n")
    print(compare_calibrations(qca, toml, ground=True).table())


if __name__ == "__main__":
    main()
