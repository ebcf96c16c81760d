"""Read/write speed of every keypoint format: 3000 frames x 5 persons (target: read < 1 s).

Run: ``python bench/bench_keypoints_io.py [--frames 3000] [--persons 5]``. The caliscope CSV
holds one person per camera, so it is timed with 1 person (its 33 landmarks per frame are
one row each). Also times the real caliscope CSV (64k rows) and the Pose2Sim OpenPose folders.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from cascalib import Tracks
from cascalib.formats import read_tracks_many, write_tracks
from cascalib.formats.keypoints import FORMATS
from cascalib.skeletons import SKELETONS

SKELETON = {"cascalib-ref": "coco17", "coco": "coco17", "mediapipe-csv": "blazepose33",
            "openpose": "body25"}
SUFFIX = {"native-json": ".json", "native-npz": ".npz", "openpose": "", "mmpose": ".json",
          "cascalib-ref": ".json", "coco": ".json", "mediapipe-csv": ".csv"}
REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def scene(n_frames: int, n_persons: int, skeleton: str, rng: np.random.Generator) -> Tracks:
    sk = SKELETONS[skeleton]
    kp = np.empty((n_frames, n_persons, sk.n_joints, 3))
    kp[..., 0] = rng.uniform(0, 1920, kp.shape[:3])
    kp[..., 1] = rng.uniform(0, 1080, kp.shape[:3])
    kp[..., 2] = rng.uniform(0.1, 1.0, kp.shape[:3])
    kp[rng.random(kp.shape[:3]) < 0.05] = np.nan  # 5 % missing joints
    if skeleton == "blazepose33":
        kp[~np.isnan(kp[..., 2])] = kp[~np.isnan(kp[..., 2])] * [1, 1, 0] + [0, 0, 1]
    return Tracks(camera="cam0", keypoints=kp, skeleton=sk, image_size=(1920, 1080),
                  fps=30.0, timestamps=np.arange(n_frames) / 30.0)


def timed(fn, repeat: int = 3) -> float:
    """Best CPU time of this process (the 2 cores are shared: wall time measures the others)."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--persons", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print("CPU seconds (best of 3 reads, 1 write); random full-precision float coordinates")
    print(f"{'format':14s} {'frames':>6s} {'persons':>7s} {'joints':>6s} {'write s':>8s} "
          f"{'read s':>7s} {'size MB':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in FORMATS:
            n_p = 1 if fmt == "mediapipe-csv" else args.persons
            t = scene(args.frames, n_p, SKELETON.get(fmt, "halpe26"), rng)
            path = Path(tmp) / f"cam0_{fmt}{SUFFIX[fmt]}"
            w = timed(lambda t=t, path=path, fmt=fmt: write_tracks(t, path, format=fmt), 1)
            r = timed(lambda t=t, path=path: read_tracks_many(path, skeleton=t.skeleton))
            size = sum(f.stat().st_size for f in path.glob("*")) if path.is_dir() \
                else path.stat().st_size
            print(f"{fmt:14s} {args.frames:6d} {n_p:7d} {t.n_joints:6d} {w:8.3f} {r:7.3f} "
                  f"{size / 1e6:8.2f}")
    if REAL.is_dir():
        csv_path = REAL / "caliscope_4cam" / "xy_HOLISTIC.csv"
        r = timed(lambda: read_tracks_many(csv_path))
        print(f"real caliscope xy_HOLISTIC.csv (64k rows, 4 cameras): read {r:.3f} s")
        pose = REAL / "pose2sim_demo" / "multi_person" / "pose"
        r = timed(lambda: [read_tracks_many(p) for p in sorted(pose.glob("cam*_json"))])
        print(f"real Pose2Sim multi_person OpenPose (4 x 100 files): read {r:.3f} s")


if __name__ == "__main__":
    main()
