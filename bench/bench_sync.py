"""Benchmark of stages II-IV (time sync + ground alignment) on simulated scenes.

Stage I is replaced by the TRUE cameras expressed in per-camera plane frames (random yaw and
shift: exactly the ambiguity stage I leaves), optionally with stage-I-like errors (focal, tilt,
metric scale). Prints three tables:

1. simulator scenes with windows cut so that offsets span -50 % .. +50 % of the sequence, mixed
   frame rates (25/30 fps) and clock drift;
2. the paper's sync experiment (Table "Temporal synchronization", Human3.6M-like: one person
   walking laps of a loop, 50 fps, offsets 0-200 frames) next to the paper's numbers, with the
   ankles of the stage II-IV test scene (2) and in the full simulator (2b);
3. run time for 4 cameras x 3000 frames x 5 persons (min / median / max of repeated runs).

With ``--refine``, table 1 also runs Stage V (the bundle adjustment with its sub-frame clock
search) from each stage II-IV result and gives the offset errors after it: the issue's sub-frame
target may be met "after this stage or after the bundle adjustment".

    python bench/bench_sync.py            # full (several minutes on 2 shared cores)
    python bench/bench_sync.py --quick    # one seed per scene
    python bench/bench_sync.py --quick --only scenes --refine   # + Stage V (about 5 min more)
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "stages"))
from align_scene import (  # noqa: E402
    make_scene,
    paper_walker_scene,
    simulated_windows,
    stage1_like,
)

from cascalib.metrics import compare_calibrations, rotation_error_in_sigmas  # noqa: E402
from cascalib.simulate import simulate  # noqa: E402
from cascalib.stages.align import AlignConfig, align_cameras  # noqa: E402
from cascalib.stages.refine import refine  # noqa: E402
from cascalib.workers import can_fork  # noqa: E402

# Paper, Table "Temporal synchronization experiments" (pred f columns: mean, median, std).
PAPER = {0: (2.90, 2.5, 14.05), 50: (52.81, 52.5, 14.12), 100: (102.67, 102, 14.22),
         150: (153.48, 153, 15.04), 200: (189.26, 201, 51.70)}


def shared_clock_error(est, truth, n_frames: int, n_ref: int) -> float:
    """Largest clock error (reference frames) over the camera's frames that show a time the
    reference camera also recorded. The offset error is the clock error at the camera's frame
    0, which for a camera that starts long before the reference extrapolates the rate error
    beyond the frames the two share."""
    k = np.arange(n_frames)
    shown = truth.time_offset + truth.time_rate * k
    err = (est.time_offset - truth.time_offset) + (est.time_rate - truth.time_rate) * k
    inside = (shown >= 0) & (shown <= n_ref - 1)
    return float(np.abs(err[inside]).max()) if inside.any() else float("nan")


def run_scene(preset: str, seed: int, *, errors: bool, with_refine: bool = False
              ) -> dict[str, object]:
    tracks, truth, plane = simulated_windows(preset, seed, errors=errors)
    t0 = time.perf_counter()
    res = align_cameras(tracks, plane, rng=seed)
    dt = time.perf_counter() - t0
    err = compare_calibrations(res.calibration, truth, ground=True)
    rows = [r for r in err.cameras if r.camera != truth.reference_camera]
    L = tracks[0].n_frames
    true_off = [abs(truth[r.camera].time_offset) / L for r in rows]
    serious = {"ambiguous", "inconsistent", "not_aligned"}
    bad = [r for r in rows if abs(r.time_offset_error_frames) >= 0.5]
    bad_flagged = sum(bool(serious & set(res.flags[r.camera])) for r in bad)
    off_v: list[float] = []
    rate_v: list[float] = []
    shared_v: list[float] = []
    z_v: list[float] = []
    rot_v: list[float] = []
    rot_z_v: list[float] = []
    if with_refine:  # Stage V from this result, default settings (as the pipeline runs it)
        result_v = refine(tracks, res.calibration, height=1.70, rng=seed,
                          rate_measured=res.rate_measured)
        refined = result_v.calibration
        err_v = compare_calibrations(refined, truth, ground=True)
        rows_v = [r for r in err_v.cameras if r.camera != truth.reference_camera]
        # geodesic relative rotation between camera pairs: whether Stage V kept the geometry
        rot_v = [err_v.summary.pairwise_rotation_error_deg_max]
        # each camera's rotation error (relative to the reference) in units of the quality
        # report's 1-sigma of that relative rotation: whether the report can be trusted
        rot_z_v = rotation_error_in_sigmas(
            err_v, {n: q.sigma_rotation_deg for n, q in result_v.quality.items()})
        # the quality report's 1-sigma of each offset, in units of which the error is counted
        z_v = [abs(r.time_offset_error_frames)
               / result_v.quality[r.camera].sigma_time_offset_frames for r in rows_v]
        off_v = [abs(r.time_offset_error_frames) for r in rows_v]
        rate_v = [abs(r.time_rate_error_pct) for r in rows_v]
        shared_v = [shared_clock_error(refined[r.camera], truth[r.camera],
                                       tracks[truth.names.index(r.camera)].n_frames, L)
                    for r in rows_v]
    return {"off": [abs(r.time_offset_error_frames) for r in rows], "off_v": off_v,
            "rate_v": rate_v, "shared_v": shared_v, "z_v": z_v, "rot_v": rot_v,
            "rot_z_v": rot_z_v,
            "bad": len(bad), "bad_flagged": bad_flagged,
            "rate": [abs(r.time_rate_error_pct) for r in rows],
            "rot": [r.rotation_error_deg for r in rows],
            "pos": [r.center_error_similarity for r in rows],
            "span": max(true_off), "time": dt, "frames": L,
            "flags": sum(bool(serious & set(f)) for f in res.flags.values())}


def table_scenes(seeds: list[int], with_refine: bool = False) -> None:
    print("\n## 1. Simulator scenes: offsets up to +-50 % of the sequence, 25/30 fps in turn, "
          "drift 1e-4 s.d.; stage-I errors: focal 3 %, tilt 1 deg, scale 5 %")
    print(f"{'scene':10s} {'I-err':5s} {'cams':>4s} {'frames':>6s} {'max|off|/L':>10s} "
          f"{'int ok':>7s} {'off med':>7s} {'off max':>7s} {'rate max%':>9s} {'rot max':>7s} "
          f"{'pos max':>7s} {'flags':>5s} {'bad flagged':>11s} {'time s':>6s}"
          + (f" | {'V int ok':>8s} {'V off med':>9s} {'V off max':>9s} {'V shared max':>12s} "
             f"{'V rate max%':>11s} {'V in 1/2 sd':>11s} {'V rot max':>9s} {'V rot z':>7s}"
             if with_refine else ""))
    total, exact, total_v, exact_v = 0, 0, 0, 0
    z_all: list[float] = []
    rot_z_all: list[float] = []
    for preset in ("terrace", "lab_ring", "crowd", "periodic"):
        for errors in (False, True):
            acc: dict[str, list[float]] = {k: [] for k in ("off", "off_v", "shared_v", "rate",
                                                           "rate_v", "z_v", "rot_v", "rot_z_v",
                                                           "rot", "pos")}
            span, tsum, frames, flags, bad, bad_flagged = 0.0, 0.0, 0, 0, 0, 0
            for seed in seeds:
                r = run_scene(preset, seed, errors=errors, with_refine=with_refine)
                for k in acc:
                    acc[k] += r[k]  # type: ignore[operator]
                span = max(span, r["span"])  # type: ignore[call-overload]
                tsum += r["time"]  # type: ignore[operator]
                frames = r["frames"]  # type: ignore[assignment]
                flags += r["flags"]  # type: ignore[operator]
                bad += r["bad"]  # type: ignore[operator]
                bad_flagged += r["bad_flagged"]  # type: ignore[operator]
            off = np.array(acc["off"])
            ok = int((off < 0.5).sum())
            total, exact = total + off.size, exact + ok
            print(f"{preset:10s} {'yes' if errors else 'no':5s} {off.size:4d} {frames:6d} "
                  f"{span:10.2f} {ok:3d}/{off.size:<3d} {np.median(off):7.3f} {off.max():7.3f} "
                  f"{max(acc['rate']):9.4f} {max(acc['rot']):7.2f} {max(acc['pos']):7.3f} "
                  f"{flags:5d} {bad_flagged:5d}/{bad:<5d} {tsum / len(seeds):6.2f}", end="")
            if with_refine:
                off_v = np.array(acc["off_v"])
                ok_v = int((off_v < 0.5).sum())
                total_v, exact_v = total_v + off_v.size, exact_v + ok_v
                z = np.array(acc["z_v"])
                z_all += acc["z_v"]
                rot_z_all += acc["rot_z_v"]
                print(f" | {ok_v:4d}/{off_v.size:<3d} {np.median(off_v):9.3f} {off_v.max():9.3f}"
                      f" {np.nanmax(acc['shared_v']):12.3f} {max(acc['rate_v']):11.4f}"
                      f" {(z <= 1).sum():5d}/{(z <= 2).sum():<5d} {max(acc['rot_v']):9.3f}"
                      f" {max(acc['rot_z_v']):7.2f}",
                      end="")
            print()
    print(f"integer part exact (|error| < 0.5 frame): {exact}/{total} = {100 * exact / total:.1f} %"
          " of non-reference cameras; flags = cameras flagged ambiguous/inconsistent/not aligned;"
          " bad flagged = wrong cameras (|error| >= 0.5) that carry such a flag")
    if with_refine:
        print(f"after Stage V (V columns): integer part exact {exact_v}/{total_v} = "
              f"{100 * exact_v / total_v:.1f} %; V off = |offset error| (frames) after the "
              "bundle adjustment's sub-frame search; V shared max = largest clock error over "
              "the frames a camera shares with the reference (the offset error at frame 0 "
              "extrapolates the rate error there); V in 1/2 sd = cameras whose offset error is "
              "within 1 / 2 of the quality report's sigma_time_offset_frames (all cameras: "
              f"{100 * np.mean(np.array(z_all) <= 1):.0f} % / "
              f"{100 * np.mean(np.array(z_all) <= 2):.0f} %; 68 / 95 % for a calibrated "
              "1-sigma); V rot max = largest relative-rotation error (deg, geodesic) of any "
              "camera pair after Stage V; V rot z = largest rotation error of a camera "
              "(relative to the reference) in units of the quality report's 1-sigma of it, "
              "hypot(sigma_rotation_deg of the camera, of the reference) (all cameras: "
              f"{100 * np.mean(np.array(rot_z_all) <= 1):.0f} % / "
              f"{100 * np.mean(np.array(rot_z_all) <= 2):.0f} % within 1 / 2 sigma)")


def table_paper(n_subjects: int) -> None:
    print("\n## 2. Paper's sync experiment, Human3.6M-like: 1 person walking laps of an oval "
          "at 1.3 m/s (8 s per lap, so distance-from-centre repeats every 4 s = 200 frames as "
          "in the paper's failure case), lap-to-lap path variation 0.15 m, 2 cameras, 50 fps, "
          "1000 frames")
    print(f"{'offset':>6s} | {'ours mean':>9s} {'median':>7s} {'std':>6s} {'max|err|':>8s} "
          f"{'flagged':>7s} | {'paper mean':>10s} {'median':>7s} {'std':>6s}")
    for off in (0, 50, 100, 150, 200):
        pred, flagged = [], 0
        for s in range(n_subjects):
            sc = make_scene(n_cams=2, n_persons=1, n_ref_frames=1000, fps=[50.0, 50.0],
                            offsets=[0.0, float(off)], path="loop", period=8.0,
                            variability=0.15, seed=100 + s)
            res = align_cameras(sc.tracks, sc.plane, rng=s)
            # paper convention: predicted shift of the second video (positive = later start)
            pred.append(res.calibration.cameras[1].time_offset)
            flagged += bool(res.flags["cam1"])
        p = np.array(pred)
        pm = PAPER[off]
        print(f"{off:6d} | {p.mean():9.2f} {np.median(p):7.2f} {p.std():6.2f} "
              f"{np.abs(p - off).max():8.2f} {flagged:7d} | {pm[0]:10.2f} {pm[1]:7.1f} "
              f"{pm[2]:6.2f}")


def table_paper_full(n_subjects: int) -> None:
    print("\n## 2b. The same experiment in the full simulator: 26 joints with detector noise, "
          "a circle of 1.66 m radius wobbling 0.15 m from lap to lap, stage-I errors (focal 3 %, "
          "tilt 1 deg, scale 5 %)")
    print(f"{'offset':>6s} | {'ours mean':>9s} {'median':>7s} {'max|err|':>8s} {'int ok':>6s} "
          f"{'wrong':>5s} {'flagged':>7s} {'wrong flagged':>13s} | {'paper mean':>10s} "
          f"{'median':>7s} {'std':>6s}")
    for off in PAPER:
        err, flagged, wrong_flagged = [], 0, 0
        for s in range(n_subjects):
            tracks, plane, true_off = paper_walker_scene(off, s)
            res = align_cameras(tracks, plane, rng=s)
            err.append(res.calibration.cameras[1].time_offset - true_off)
            flag = bool(res.flags["cam1"])
            flagged += flag
            wrong_flagged += flag and abs(err[-1]) >= 0.5
        e = np.array(err)
        wrong = int((np.abs(e) >= 0.5).sum())
        pm = PAPER[off]
        print(f"{off:6d} | {off + e.mean():9.2f} {off + np.median(e):7.2f} {np.abs(e).max():8.2f} "
              f"{n_subjects - wrong:3d}/{n_subjects:<2d} {wrong:5d} {flagged:7d} "
              f"{wrong_flagged:13d} | {pm[0]:10.2f} {pm[1]:7.1f} {pm[2]:6.2f}")


def _cpu_seconds() -> float:
    """CPU time of this process and of its finished worker processes."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def table_time(repeats: int = 5) -> None:
    print("\n## 3. Run time: 4 cameras x 3000 frames x 5 persons (30 fps, terrace rig)")
    sc = simulate("terrace", seed=0, **{"timing.fps": (30.0,), "duration_s": 100.5,
                                        "timing.max_offset_s": 0.0})
    rng = np.random.default_rng(0)
    plane = [stage1_like(c, rng, errors=False) for c in sc.truth.cameras]
    cfg = AlignConfig()
    walls, cpus = [], []
    for _ in range(repeats):  # the same work each time: the spread is the machine's
        t0, c0 = time.perf_counter(), _cpu_seconds()
        align_cameras(sc.tracks, plane, cfg, rng=0)
        walls.append(time.perf_counter() - t0)
        cpus.append(_cpu_seconds() - c0)
    workers = "processes" if cfg.processes and can_fork() else "threads"
    print(f"frames per camera {[t.n_frames for t in sc.tracks]}, persons {len(sc.heights)}, "
          f"{repeats} runs ({cfg.n_workers} worker {workers}; CPU: this process and its "
          "workers):")
    print("| | min | median | max |\n|---|---|---|---|")
    for name, v in (("wall s", walls), ("CPU s", cpus)):
        print(f"| {name} | {min(v):.2f} | {np.median(v):.2f} | {max(v):.2f} |")
    print("The cores are shared with other jobs, whose load changes within minutes (the CPU "
          "time of the same work varies with it): the smallest wall time is the closest to the "
          "code's own, the largest an upper bound.")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one seed per scene, 3 subjects")
    ap.add_argument("--only", choices=("scenes", "paper", "time"), default=None)
    ap.add_argument("--refine", action="store_true",
                    help="table 1 also runs Stage V and gives the offset errors after it")
    ap.add_argument("--repeats", type=int, default=5, help="runs of the time table (3.)")
    args = ap.parse_args()
    seeds = [0] if args.quick else [0, 1, 2]
    if args.only in (None, "scenes"):
        table_scenes(seeds, args.refine)
    if args.only in (None, "paper"):
        table_paper(3 if args.quick else 7)
        table_paper_full(3 if args.quick else 7)
    if args.only in (None, "time"):
        table_time(args.repeats)


if __name__ == "__main__":
    main()
