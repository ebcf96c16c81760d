"""Benchmark of stage V (joint camera refinement) on simulated rigs, beside the paper's numbers.

Starts from the true rig perturbed by the errors stages II-IV leave (rotation ~3 deg, position
~0.3 m, focal ~5 %, time offset ~0.5 frame) and prints:

1. accuracy per preset (median/max relative rotation, focal, centres after a similarity
   alignment, metric scale, time offsets, verdicts, calibrated uncertainty vs true error);
2. the paper's numbers (Terrace 1.82 deg / 138 mm; Human3.6M-like 2-11 deg) beside ours;
3. time of the refinement vs sequence length (frame selection keeps it sub-linear);
4. distortion: estimating it vs ignoring it on the "phones" and "security" presets, and the
   lens pass first (default) vs only at the end;
5. whether the images determine the principal point at all (noise-free, synchronised data);
6. what the principal point costs: the whole cascade as it is, beside Stage V from the same
   stage II-IV rig given the true principal points (focal lengths still estimated).

Usage::

    python bench/bench_refine.py                 # all tables (several minutes on 2 cores)
    python bench/bench_refine.py --quick         # one seed, fewer presets
    python bench/bench_refine.py --table timing  # one table
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cascalib.calibration import Calibration
from cascalib.geometry import rodrigues_to_matrix, rotation_angle_deg, umeyama
from cascalib.simulate import PRESETS, simulate
from cascalib.stages.refine import RefineConfig, refine
from cascalib.tracks import Tracks

PAPER = {"terrace": "1.82 deg / 138 mm (EPFL Terrace, Table 4)",
         "lab_ring": "2-11 deg (Human3.6M 4 cams, Table 5)",
         "crowd": "n/a (paper: at most 3-4 people)",
         "phones": "n/a"}


def perturb(calib: Calibration, rng: np.random.Generator, *, rot_deg: float = 3.0,
            pos_m: float = 0.3, focal_rel: float = 0.05, offset: float = 0.5) -> Calibration:
    """The rig with random errors of the sizes stages II-IV leave (reference clock kept)."""
    cams = []
    for i, cam in enumerate(calib.cameras):
        axis = rng.normal(size=3)
        R = rodrigues_to_matrix(axis / np.linalg.norm(axis) * np.radians(rot_deg)) @ cam.R
        center = cam.center + rng.normal(size=3) / np.sqrt(3) * pos_m
        K = cam.K.copy()
        K[0, 0] *= 1 + focal_rel * rng.choice([-1, 1])
        K[1, 1] = K[0, 0]
        K[:2, 2] = cam.image_centre
        off = cam.time_offset + (0.0 if i == 0 else offset * rng.choice([-1, 1]))
        cams.append(cam.with_(R=R, t=-R @ center, K=K, dist=np.zeros(5), time_offset=off))
    return Calibration(cams, reference_camera=calib.reference_camera)


def errors(est: Calibration, truth: Calibration, people: float = 1.0) -> dict[str, float]:
    """Relative rotations, focal, centres after similarity, scale, offsets.

    ``people`` is the scene's mean person height over the height prior: the height prior can
    only give the metric scale up to it, so ``scale_people`` is the scale error with that
    factor taken out (the method's own share; ``scale`` includes the sample's).
    """
    n = len(truth)
    rel = [rotation_angle_deg((est.cameras[i].R @ est.cameras[j].R.T)
                              @ (truth.cameras[i].R @ truth.cameras[j].R.T).T)
           for i in range(n) for j in range(i + 1, n)]
    c_est = np.array([c.center for c in est])
    c_true = np.array([c.center for c in truth])
    s, R, t = umeyama(c_est, c_true)
    pos = np.linalg.norm(s * c_est @ R.T + t - c_true, axis=1)
    focal = [abs(e.focal / g.focal - 1) for e, g in zip(est, truth, strict=True)]
    off = [abs(e.time_offset - g.time_offset) for e, g in zip(est, truth, strict=True)]
    return dict(rot_med=float(np.median(rel)), rot_max=float(np.max(rel)),
                focal_med=100 * float(np.median(focal)), focal_max=100 * float(np.max(focal)),
                pos_med=100 * float(np.median(pos)), pos_max=100 * float(np.max(pos)),
                scale=100 * abs(1 / s - 1), scale_people=100 * abs(people / s - 1),
                off_max=float(np.max(off)))


def truncate(tracks: list[Tracks], truth: Calibration, n_frames: int) -> list[Tracks]:
    """The first ``n_frames`` reference frames of every camera."""
    out = []
    for tr, cam in zip(tracks, truth, strict=True):
        last = int(np.ceil((n_frames - cam.time_offset) / cam.time_rate))
        out.append(tr.with_(keypoints=tr.keypoints[: max(last, 1)],
                            track_ids=None if tr.track_ids is None else tr.track_ids[:last],
                            timestamps=None if tr.timestamps is None else tr.timestamps[:last]))
    return out


#: The height prior (m) every refinement here gets: the simulator's mean, not the scene's.
HEIGHT = 1.70

START_SCALE = 1.0  # --start-scale: fraction of the stage II-IV error sizes to start from


def run(preset: str, seed: int, cfg: RefineConfig, n_frames: int | None = None,
        duration_s: float | None = None):
    conf = PRESETS[preset].model_copy(update={"duration_s": duration_s}) if duration_s else preset
    scene = simulate(conf, seed=seed)
    tracks = scene.tracks
    if n_frames is not None:
        tracks = truncate(tracks, scene.truth, n_frames)
    k = START_SCALE
    init = perturb(scene.truth, np.random.default_rng(100 + seed), rot_deg=3.0 * k,
                   pos_m=0.3 * k, focal_rel=0.05 * k, offset=0.5 * k)
    t0 = time.perf_counter()
    res = refine(tracks, init, cfg, height=HEIGHT, rng=seed)
    dt = time.perf_counter() - t0
    return scene, init, res, dt


def table_accuracy(presets: list[str], seeds: list[int]) -> None:
    k = START_SCALE
    print(f"\n## Accuracy (start: truth + {3 * k:.2g} deg, {0.3 * k:.2g} m, {5 * k:.2g} % focal, "
          f"{0.5 * k:.2g} frame)")
    print("| preset | seed | cams | rel.rot med/max deg | focal med/max % | centre med/max cm |"
          " scale % (vs people) | offset max fr | verdicts | sigma/err rot | time s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for preset in presets:
        for seed in seeds:
            scene, init, res, dt = run(preset, seed, RefineConfig())
            e0 = errors(init, scene.truth)
            e = errors(res.calibration, scene.truth, float(scene.heights.mean()) / HEIGHT)
            verdicts = "".join(q.verdict[0] for q in res.quality.values())
            abs_rot = [rotation_angle_deg(c.R @ g.R.T) for c, g in
                       zip(res.calibration, scene.truth, strict=True)]
            sig = np.median([q.sigma_rotation_deg for q in res.quality.values()])
            print(f"| {preset} | {seed} | {len(scene.truth)} | "
                  f"{e['rot_med']:.3f}/{e['rot_max']:.3f} (start {e0['rot_med']:.2f}) | "
                  f"{e['focal_med']:.2f}/{e['focal_max']:.2f} | "
                  f"{e['pos_med']:.1f}/{e['pos_max']:.1f} | {e['scale']:.2f} "
                  f"({e['scale_people']:.2f}) | {e['off_max']:.3f}"
                  f" | {verdicts} | {sig:.2f}/{np.median(abs_rot):.2f} | {dt:.1f} |", flush=True)


def table_paper(seeds: list[int]) -> None:
    print("\n## Beside the paper (camera pose error: mean rotation deg / mean centre mm)")
    print("| setup | paper | ours (simulated equivalent) |")
    print("|---|---|---|")
    for preset in ("terrace", "lab_ring"):
        rot, pos = [], []
        for seed in seeds:
            scene, _, res, _ = run(preset, seed, RefineConfig())
            e = errors(res.calibration, scene.truth)
            rot.append(e["rot_med"])
            pos.append(e["pos_med"] * 10)
        print(f"| {preset} | {PAPER[preset]} | {np.mean(rot):.2f} deg / {np.mean(pos):.0f} mm |")


def table_timing(lengths: list[int]) -> None:
    print("\n## Time vs sequence length (terrace-like rig, 4 cameras, 5 persons)")
    print("| frames | groups associated | groups in graph | recorded solves s | total s | "
          "rot med deg |")
    print("|---|---|---|---|---|---|")
    for n in lengths:
        scene, _, res, dt = run("terrace", 0, RefineConfig(), n_frames=n,
                                duration_s=n / 25 + 3)
        e = errors(res.calibration, scene.truth)
        ba = sum(s.seconds for s in res.solves)
        print(f"| {n} | {res.association.n_groups} | {res.n_selected} | {ba:.1f} | {dt:.1f} | "
              f"{e['rot_med']:.3f} |", flush=True)
    print("recorded solves: the seconds of RefineResult.solves (the last Levenberg-Marquardt run "
          "of each round and kept pass), less than the whole time in gtsam; total: all of "
          "stage V")


def table_distortion(seeds: list[int], modes: tuple[str, ...] = ("never", "auto", "always"),
                     presets: tuple[str, ...] = ("phones", "security")) -> None:
    """Estimating the lens vs ignoring it. Mode "auto-last" is "auto" with the lens pass only
    at the end (``lens_first`` off: the rounds and the principal-point pass fit a pinhole)."""
    print("\n## Distortion: estimating vs ignoring it (auto-last: lens pass only at the end)")
    print("| preset | seed | model | rel.rot med/max deg | focal med % | centre med cm | "
          "pp error med px | reproj med px |")
    print("|---|---|---|---|---|---|---|---|")
    for preset in presets:
        for seed in seeds:
            for mode in modes:
                cfg = RefineConfig(distortion="auto" if mode == "auto-last" else mode,
                                   lens_first=mode != "auto-last")
                scene, _, res, _ = run(preset, seed, cfg)
                e = errors(res.calibration, scene.truth)
                rep = np.median([q.reprojection_median_px for q in res.quality.values()])
                pp = np.median([np.linalg.norm(c.principal_point - g.principal_point)
                                for c, g in zip(res.calibration, scene.truth, strict=True)])
                print(f"| {preset} | {seed} | {mode} (used: {res.distortion}) | "
                      f"{e['rot_med']:.3f}/{e['rot_max']:.3f} | {e['focal_med']:.2f} | "
                      f"{e['pos_med']:.1f} | {pp:.1f} | {rep:.2f} |", flush=True)


def table_principal_point(seeds: list[int]) -> None:
    """Is the principal point in the images at all? Noise-free, synchronised terrace scenes.

    Both runs start from the true rig with the principal point at the image centre (where
    stages I-IV put it), the true clocks, no bone terms and a principal-point prior of one image
    width (so the images, not the priors, decide). "held" keeps the true intrinsics. When the
    free run reprojects as well as the held one while its principal point and rotations are
    off, the images do not determine the principal point: only priors can.
    """
    print("\n## Principal point on noise-free, synchronised data (terrace, 40 s, no bone terms)")
    print("| seed | intrinsics | reproj med px | pp error px med/max | rel.rot med/max deg |")
    print("|---|---|---|---|---|")
    from cascalib.simulate.detector import DetectorConfig
    for seed in seeds:
        conf = PRESETS["terrace"].model_copy(update={
            "duration_s": 40.0, "detector": DetectorConfig.clean(),
            "timing": PRESETS["terrace"].timing.model_copy(update={"max_offset_s": 0.0})})
        scene = simulate(conf, seed=seed)
        start = Calibration([c.with_centred_principal_point() for c in scene.truth.cameras],
                            reference_camera=scene.truth.reference_camera)
        cfg = RefineConfig(refine_time=False, use_bones=False, principal_point="always",
                           principal_point_sigma=1.0, distortion="never")
        for label, init, fixed in (("free", start, ()),
                                   ("held (true)", scene.truth, tuple(scene.truth.names))):
            res = refine(scene.tracks, init, cfg, height=float(scene.heights.mean()), rng=seed,
                         fixed_intrinsics=fixed)
            e = errors(res.calibration, scene.truth)
            pp = [np.linalg.norm(c.K[:2, 2] - g.K[:2, 2])
                  for c, g in zip(res.calibration, scene.truth, strict=True)]
            rep = np.median([q.reprojection_median_px for q in res.quality.values()])
            print(f"| {seed} | {label} | {rep:.3f} | {np.median(pp):.1f}/{np.max(pp):.1f} | "
                  f"{e['rot_med']:.3f}/{e['rot_max']:.3f} |", flush=True)


def table_known_principal_point(presets: list[str], seeds: list[int]) -> None:
    """The whole cascade (40 s scenes), and Stage V run again from its stage II-IV rig with each
    camera's principal point set to the true one and held (``principal_point="never"``: the
    rounds' ``Cal3f`` keeps the given point; focal, pose and clocks are estimated as usual)."""
    from cascalib.config import CalibrationConfig
    from cascalib.pipeline import calibrate

    print("\n## What the principal point costs (40 s scenes; stage V from the same stage II-IV "
          "rig)")
    print("| preset | seed | as is: rot med/max deg | focal max % | centre max cm | "
          "true pp: rot med/max deg | focal max % | centre max cm |")
    print("|---|---|---|---|---|---|---|---|")
    for preset in presets:
        for seed in seeds:
            scene = simulate(preset, seed=seed, duration_s=40.0)
            res = calibrate(scene.tracks, CalibrationConfig(seed=0))
            start = res.alignment.calibration
            held = [cam.with_(K=np.array([[cam.K[0, 0], 0, scene.truth[cam.name].K[0, 2]],
                                          [0, cam.K[1, 1], scene.truth[cam.name].K[1, 2]],
                                          [0, 0, 1.0]]))
                    for cam in start.cameras]
            init = Calibration(held, reference_camera=start.reference_camera, world=start.world)
            known = refine(scene.tracks, init, RefineConfig(principal_point="never"),
                           height=HEIGHT, rng=0).calibration
            cells = []
            for est in (res.calibration, known):
                e = errors(est, scene.truth)
                cells.append(f"{e['rot_med']:.2f}/{e['rot_max']:.2f} | {e['focal_max']:.2f} | "
                             f"{e['pos_max']:.1f}")
            print(f"| {preset} | {seed} | {cells[0]} | {cells[1]} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--table", choices=["accuracy", "paper", "timing", "distortion",
                                        "principal-point", "known-principal-point"])
    ap.add_argument("--presets", nargs="+", help="presets of the accuracy table")
    ap.add_argument("--modes", nargs="+", default=["never", "auto-last", "auto", "always"],
                    help="distortion modes of the distortion table (auto-last: lens pass only "
                    "at the end)")
    ap.add_argument("--lengths", nargs="+", type=int, help="frame counts of the timing table")
    ap.add_argument("--start-scale", type=float, default=1.0,
                    help="scale of the start errors (1 = 3 deg, 0.3 m, 5 %%, 0.5 frame)")
    args = ap.parse_args()
    global START_SCALE
    START_SCALE = args.start_scale
    print(f"start errors: {3 * START_SCALE:.2g} deg, {0.3 * START_SCALE:.2g} m, "
          f"{5 * START_SCALE:.2g} % focal, {0.5 * START_SCALE:.2g} frame")
    seeds = [0] if args.quick else [0, 1, 2]
    presets = args.presets or (["terrace", "lab_ring"] if args.quick
                               else ["terrace", "lab_ring", "crowd"])
    if args.table in (None, "accuracy"):
        table_accuracy(presets, seeds)
    if args.table in (None, "paper"):
        table_paper(seeds)
    if args.table in (None, "timing"):
        table_timing(args.lengths or ([250, 1000] if args.quick else [250, 500, 1000, 2000, 3000]))
    if args.table in (None, "distortion"):
        table_distortion(seeds, tuple(args.modes))
    if args.table in (None, "principal-point"):
        table_principal_point(seeds)
    if args.table in (None, "known-principal-point"):
        table_known_principal_point(args.presets or ["terrace", "lab_ring", "crowd", "periodic"],
                                    seeds)


if __name__ == "__main__":
    main()
