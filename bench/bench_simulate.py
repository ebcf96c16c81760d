"""Simulation speed vs cameras, frames and persons (target: 4 cameras x 3000 frames x 5 persons
with the realistic detector in well under 10 s).

Run: ``python bench/bench_simulate.py [--quick]``. Prints one row per setting: total time and
its split into people (paths and timelines), 3D joints (the gait sampled at every camera's
frames) and the detector (projection, noise, occlusion, ids).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cascalib.simulate import preset
from cascalib.simulate.detector import detect
from cascalib.simulate.people import make_people
from cascalib.simulate.rigs import make_rig
from cascalib.simulate.scene import joints_at, simulate

FPS = 30.0


def run_one(n_cameras: int, n_frames: int, n_persons: int, seed: int = 0) -> dict[str, float]:
    cfg = preset("terrace").with_(**{"rig.n_cameras": n_cameras, "people.n_persons": n_persons,
                                     "duration_s": n_frames / FPS + 3.5,
                                     "timing.fps": (FPS,)})
    t0 = time.perf_counter()
    scene = simulate(cfg, seed=seed)
    total = time.perf_counter() - t0
    # The split, re-timed on the same configuration.
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    people = make_people(cfg.people, cfg.duration_s, rng)
    t1 = time.perf_counter()
    cams = make_rig(cfg.rig, cfg.people.area, rng)
    heights = np.array([p.height for p in people])
    x = [joints_at(people, c.frame_times()) for c in scene.clocks]
    t2 = time.perf_counter()
    for cam, xc in zip(cams, x, strict=True):
        detect(cam, xc, heights, cfg.detector, rng)
    t3 = time.perf_counter()
    frames = int(np.mean([t.n_frames for t in scene.tracks]))
    return {"total": total, "people": t1 - t0, "joints": t2 - t1, "detector": t3 - t2,
            "frames": frames}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="only the target setting")
    args = ap.parse_args()
    grid = [(4, 3000, 5)]
    if not args.quick:
        grid += [(1, 3000, 5), (8, 3000, 5), (4, 1000, 5), (4, 10000, 5), (4, 3000, 1),
                 (4, 3000, 15)]
    print(f"{'cameras':>7} {'frames':>7} {'persons':>7} | {'total s':>8} {'people':>7} "
          f"{'joints':>7} {'detector':>8}")
    for n_cam, n_frames, n_persons in grid:
        r = run_one(n_cam, n_frames, n_persons)
        print(f"{n_cam:7d} {r['frames']:7d} {n_persons:7d} | {r['total']:8.2f} "
              f"{r['people']:7.2f} {r['joints']:7.2f} {r['detector']:8.2f}")


if __name__ == "__main__":
    main()
