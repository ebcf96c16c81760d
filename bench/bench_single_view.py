"""Benchmark of Stage I (single-view focal length and ground plane).

Prints, side by side with the CasCalib supplement's numbers:

* ``protocol``: the supplement's single-view simulation protocol (cascalib.simulate.paper_protocol:
  measurement noise, height variation and number-of-people sweeps), mean and median focal and
  normal errors over the trials that returned an estimate, and the failure rate;
* ``presets``: the simulator's terrace and lab_ring scenes with the realistic detector;
* ``limits``: what bounds the presets' errors: the same scenes with the principal point truly at
  the image centre, then also a perfect detector, then also upright walkers (no forward trunk
  lean), and the default scenes recorded 4 times longer;
* ``speed``: time per camera for 3000 frames x 5 persons;
* ``real``: the real Pose2Sim and caliscope data against their reference calibrations.

Usage: ``python bench/bench_single_view.py [--part protocol|presets|limits|speed|real|all]
[--trials N] [--seeds N] [--duration S]``.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from cascalib.errors import EstimationFailed
from cascalib.simulate import paper_protocol as pp
from cascalib.stages.single_view import SingleViewConfig, calibrate_single_view
from cascalib.stages.single_view_fit import fit_observations
from cascalib.stages.single_view_solver import Observations

# The supplement's tables (Simulations): rows f_x %, f_y %, N (deg), fail %.
PAPER = {
    "measurement_noise": {
        "fx": [1.85, 3.45, 6.88, 9.70, 16.83, 27.03], "fy": [1.08, 1.81, 3.66, 6.01, 10.13, 17.75],
        "N": [0.15, 0.26, 0.60, 1.09, 2.22, 4.30], "fail": [0.82, 1.52, 3.4, 5.5, 8.04, 17.36]},
    "height_variation": {
        "fx": [7.00, 8.75, 10.36, 10.71, 13.22], "fy": [3.64, 4.258, 5.27, 6.04, 6.48],
        "N": [0.58, 0.63, 0.82, 0.87, 1.05], "fail": [2.62, 3.5, 4.18, 4.7, 5.98]},
    "number_of_people": {
        "fx": [27.33, 27.68, 26.29, 18.21, 21.98], "fy": [32.40, 25.64, 25.25, 14.94, 14.17],
        "N": [3.74, 3.33, 2.62, 1.76, 1.13], "fail": [15.98, 12.2, 8.8, 5.72, 3.78]},
}

#: The protocol's "height" is the ankle-to-shoulder distance the DLT assumes (no body ratios),
#: the principal point is the image centre, the noise is isotropic pixel noise (no gait, so the
#: ankle is trusted sideways too) and nothing is refused here (the refusal is applied when
#: scoring, see (b)).
PROTOCOL_CONFIG = dict(joint_height_ratios={"ankle": 0.0, "shoulder": 1.0, "neck": 1.0,
                                            "head_top": 1.0},
                       principal_point="center", max_focal_uncertainty=float("inf"),
                       min_ankle_spread=0.0, ankle_sideways_weight=1.0)


def protocol_trial(s: pp.ProtocolSample, assumed: float, cfg: SingleViewConfig,
                   seed: int) -> dict[str, float] | None:
    n = len(s.ankles)
    obs = Observations(s.ankles, s.shoulders[:, None, :], np.full((n, 1), assumed),
                       np.full(n, -1, dtype=np.int64))
    try:
        fit = fit_observations(obs, s.image_size, cfg, rng=seed)
    except EstimationFailed:
        return None
    out = pp.errors(s, fit.model.f, fit.model.n, fit.model.d)
    lo, hi = fit.focal_interval
    out["half_width"] = (hi - lo) / (2 * fit.model.f)
    return out


def _table(name: str, vals: list, rows: dict, paper: dict) -> None:
    print("| metric | " + " | ".join(f"{v:g}" for v in vals) + " |")
    print("|---" * (len(vals) + 1) + "|")
    print("| f % ours | " + " | ".join(f"{m:.2f} ({md:.2f})" for m, md in rows["f"]) + " |")
    print("| f_x % paper | " + " | ".join(f"{v:.2f}" for v in paper["fx"]) + " |")
    print("| f_y % paper | " + " | ".join(f"{v:.2f}" for v in paper["fy"]) + " |")
    print("| N deg ours | " + " | ".join(f"{m:.2f} ({md:.2f})" for m, md in rows["N"]) + " |")
    print("| N deg paper | " + " | ".join(f"{v:.2f}" for v in paper["N"]) + " |")
    print("| rho % ours | " + " | ".join(f"{m:.2f} ({md:.2f})" for m, md in rows["rho"]) + " |")
    print("| fail % ours | " + " | ".join(f"{v:.2f}" for v in rows["fail"]) + " |")
    print("| fail % paper | " + " | ".join(f"{v:.2f}" for v in paper["fail"]) + " |")
    better = all(m < min(a, b) for (m, _), a, b in zip(rows["f"], paper["fx"], paper["fy"],
                                                      strict=True))
    better_n = all(m < p for (m, _), p in zip(rows["N"], paper["N"], strict=True))
    print(f"\nmean focal error below min(f_x, f_y) of the paper in every cell: {better}; "
          f"mean normal error below the paper's in every cell: {better_n}\n")


def _rows(results: list[list[dict | None]], max_half: float) -> dict:
    rows: dict = {k: [] for k in ("f", "N", "fail", "rho")}
    for res in results:
        ok = [r for r in res if r is not None and r["half_width"] <= max_half]
        for key, metric in (("f", "focal_pct"), ("N", "normal_deg"), ("rho", "height_pct")):
            v = np.array([r[metric] for r in ok]) if ok else np.array([np.nan])
            rows[key].append((float(np.mean(v)), float(np.median(v))))
        rows["fail"].append(100.0 * (len(res) - len(ok)) / len(res))
    return rows


def _sweep(name: str, n_trials: int, spec: dict | None = None) -> dict:
    """pp.sweep, redrawing the rare trial the protocol cannot place in view (tall outliers of
    the 0.25 m height spread)."""
    spec = spec or pp.SWEEPS[name]
    rng = np.random.default_rng(12345)
    out = {}
    for value in spec["values"]:
        kw = {**spec["fixed"], spec["vary"]: value}
        samples = []
        while len(samples) < n_trials:
            try:
                samples.append(pp.sample(rng=rng, **kw))
            except RuntimeError:
                continue
        out[value] = samples
    return out


def bench_protocol(n_trials: int, height_people: int | None = None) -> None:
    cfg = SingleViewConfig(**PROTOCOL_CONFIG)
    default_max = SingleViewConfig().max_focal_uncertainty
    print(f"\n## Paper single-view protocol ({n_trials} trials per cell; paper: 5000)\n")
    print("ours = mean (median) over the scored trials; paper = its table. Two scorings: "
          "(a) every trial that returns an estimate is scored; (b) the default refusal is on: "
          f"trials whose 95 % focal interval is wider than +-{100 * default_max:.0f} % count as "
          "failures (EstimationFailed) and are not scored.\n")
    sweeps = dict(pp.SWEEPS)
    if height_people:  # the paper does not say how many people its height sweep used
        only = pp.SWEEPS["height_variation"]
        sweeps = {"height_variation": {**only, "fixed": {**only["fixed"],
                                                        "n_people": height_people}}}
        print(f"height sweep with {height_people} people instead of 3\n")
    for name, spec in sweeps.items():
        t0 = time.perf_counter()
        trials = _sweep(name, n_trials, spec)
        results = [[protocol_trial(s, spec["assumed_height"], cfg, i)
                    for i, s in enumerate(samples)] for samples in trials.values()]
        dt = time.perf_counter() - t0
        n_total = sum(len(v) for v in trials.values())
        for label, max_half in (("(a) all scored", np.inf), ("(b) refusal on", default_max)):
            print(f"### {name} ({spec['vary']}) {label}; {1000 * dt / n_total:.1f} ms/trial\n")
            _table(name, list(trials), _rows(results, max_half), PAPER[name])


def _focal_floor(cam) -> float:
    """Focal error (%) that assuming the image centre as principal point causes by itself.

    People on a plane fix the vertical vanishing point ``v`` and the horizon ``l`` (and the
    height ratio), not the principal point's offset along the perpendicular from ``v`` to
    ``l``: every ``c`` on that line with ``f^2 = dist(v, c) dist(c, l)`` explains them equally
    (square pixels). The stage takes the image centre's foot on that line; this is its focal
    error for perfect data (about ``dc cot(2 pitch) / f`` for a pitched-down camera).
    """
    w, h = cam.image_size
    K = np.array([[cam.focal, 0, cam.principal_point[0]], [0, cam.focal, cam.principal_point[1]],
                  [0, 0, 1.0]])
    n = cam.R[:, 2]
    v = K @ n
    if abs(v[2]) < 1e-12:
        return float("nan")
    v = v[:2] / v[2]
    line = np.linalg.inv(K).T @ n
    norm = np.hypot(*line[:2])
    u = line[:2] / norm                      # unit normal of the horizon in the image
    c0 = np.array([(w - 1) / 2, (h - 1) / 2])
    c = v + u * float(np.dot(c0 - v, u))     # the centre's foot on the line v + t u
    f2 = abs(float(np.dot(c - v, u))) * abs(float(line[:2] @ c + line[2]) / norm)
    return 100 * (np.sqrt(f2) / cam.focal - 1)


def _camera_errors(res, cam) -> dict[str, float]:
    cos = float(np.clip(res.normal_cam @ cam.R[:, 2], -1.0, 1.0))
    lo, hi = res.focal_interval
    return {"f": 100 * (res.focal / cam.focal - 1), "N": float(np.degrees(np.arccos(cos))),
            "H": 100 * (res.camera_height / cam.center[2] - 1),
            "covered": float(lo <= cam.focal <= hi), "t": res.diagnostics["time_s"],
            "pp": float(np.hypot(*(res.principal_point - cam.principal_point))),
            "f_floor": _focal_floor(cam),
            # the principal point's offset towards the vertical vanishing point is not
            # observable from people (it trades off against f and tilt): with the centre assumed,
            # it tilts the estimated normal by about this much
            "floor": float(np.degrees(abs(cam.principal_point[1] - (cam.image_size[1] - 1) / 2)
                                      / cam.focal))}


def _known_pp_errors(tr, cam, seed: int) -> tuple[float, float]:
    """Oracle diagnostic: the same tracks shifted so that the true principal point is the image
    centre the stage assumes (the simulator offsets it by up to 3 % of the image, which people
    on a plane cannot reveal)."""
    w, h = cam.image_size
    kp = tr.keypoints.copy()
    kp[..., :2] -= cam.principal_point - np.array([(w - 1) / 2, (h - 1) / 2])
    far = ((kp[..., 0] < -0.2 * w) | (kp[..., 0] > 1.2 * w) | (kp[..., 1] < -0.2 * h)
           | (kp[..., 1] > 1.2 * h))
    kp[far] = np.nan
    try:
        res = calibrate_single_view(tr.with_(keypoints=kp), rng=seed)
    except EstimationFailed:
        return np.nan, np.nan
    e = _camera_errors(res, cam)
    return e["f"], e["N"]


def bench_presets(n_seeds: int, duration: float | None = None) -> None:
    from cascalib.simulate import simulate

    over = {} if duration is None else {"duration_s": duration}
    length = "" if duration is None else f", {duration:g} s scenes"
    print(f"\n## Simulator presets, realistic detector ({n_seeds} seeds, default config"
          f"{length})\n")
    print("| preset | seed | camera | f err % (pp floor) | normal err deg (pp floor) | "
          "cam height err % | "
          "95% CI covers f | pp err px | inliers/upright | time s | f err % if pp known | "
          "normal err deg if pp known |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in ("terrace", "lab_ring"):
        rows = []
        for seed in range(n_seeds):
            scene = simulate(name, seed=seed, **over)
            for tr in scene.tracks:
                cam = scene.truth[tr.camera]
                try:
                    res = calibrate_single_view(tr, rng=seed)
                except EstimationFailed as err:
                    print(f"| {name} | {seed} | {tr.camera} | refused: {err.message} |")
                    rows.append(None)
                    continue
                e = _camera_errors(res, cam)
                e["f_pp"], e["N_pp"] = _known_pp_errors(tr, cam, seed)
                rows.append(e)
                print(f"| {name} | {seed} | {tr.camera} | {e['f']:+.2f} ({e['f_floor']:+.2f}) | "
                      f"{e['N']:.2f} "
                      f"({e['floor']:.2f}) | "
                      f"{e['H']:+.2f} | {'yes' if e['covered'] else 'no'} | {e['pp']:.1f} | "
                      f"{res.n_inliers}/{len(res.inliers)} | {e['t']:.2f} | {e['f_pp']:+.2f} | "
                      f"{e['N_pp']:.2f} |")
        ok = [r for r in rows if r is not None]
        f = np.abs([r["f"] for r in ok])
        nd = np.array([r["N"] for r in ok])
        print(f"| **{name}** | all | {len(ok)}/{len(rows)} estimated | median {np.median(f):.2f}"
              f" (max {f.max():.2f}; floor {np.median(np.abs([r['f_floor'] for r in ok])):.2f})"
              f" | median {np.median(nd):.2f} (max {nd.max():.2f}; floor "
              f"{np.median([r['floor'] for r in ok]):.2f}) | "
              f"median {np.median(np.abs([r['H'] for r in ok])):.2f} | "
              f"{100 * np.mean([r['covered'] for r in ok]):.0f} % | | | "
              f"median {np.median([r['t'] for r in ok]):.2f} | "
              f"median {np.median(np.abs([r['f_pp'] for r in ok])):.2f} | "
              f"median {np.median([r['N_pp'] for r in ok]):.2f} |")
    print("\nTargets: median focal error <= 2 %, normal <= 0.5 deg. The pp floors are the errors "
          "that the principal point's unobservable offset (held at the image centre) causes "
          "with perfect data.")


#: The limits table's scene variants: label, simulator overrides (cumulative but the last),
#: and the scene length as a multiple of the preset's.
PERFECT_DETECTOR = {"detector.noise_px": 0.0, "detector.noise_rel": 0.0,
                    "detector.outlier_rate": 0.0, "detector.miss_rate": 0.0,
                    "detector.swap_rate": 0.0, "detector.false_positive_rate": 0.0}
LIMIT_VARIANTS: tuple[tuple[str, dict[str, object], float], ...] = (
    ("preset as it is", {}, 1.0),
    ("principal point at the image centre", {"rig.principal_offset": 0.0}, 1.0),
    ("+ perfect detector", {"rig.principal_offset": 0.0, **PERFECT_DETECTOR}, 1.0),
    ("+ upright walkers (no trunk lean)", {"rig.principal_offset": 0.0, **PERFECT_DETECTOR,
                                           "people.walk_trunk_pitch_rad": 0.0}, 1.0),
    ("preset, 4x longer recording", {}, 4.0),
)


def bench_limits(n_seeds: int) -> None:
    """Median errors of the presets under scene variants that remove one limit at a time."""
    from cascalib.simulate import preset, simulate

    print(f"\n## What limits the presets ({n_seeds} seeds, default config; median |focal "
          "error| % / median normal error deg / median reported focal s.d. % over the cameras)"
          "\n")
    print("The occlusions, truncation and the gait (feet apart, hip sway, bobbing) stay in every "
          "row; 'occlusion' drops joints hidden by nearer people.\n")
    print("| variant | " + " | ".join(f"{p}: f % / N deg / f sd %" for p in ("terrace", "lab_ring"))
          + " |")
    print("|---|---|---|")
    for label, over, length in LIMIT_VARIANTS:
        cells = []
        for name in ("terrace", "lab_ring"):
            kw = {**over, "duration_s": length * preset(name).duration_s}
            f, n, sd = [], [], []
            for seed in range(n_seeds):
                scene = simulate(name, seed=seed, **kw)
                for tr in scene.tracks:
                    try:
                        res = calibrate_single_view(tr, rng=seed)
                    except EstimationFailed:
                        continue
                    e = _camera_errors(res, scene.truth[tr.camera])
                    f.append(abs(e["f"]))
                    n.append(e["N"])
                    sd.append(100 * res.focal_sd_rel)
            cells.append(f"{np.median(f):.2f} / {np.median(n):.2f} / {np.median(sd):.2f}"
                         if f else "all refused")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
    print("\nTargets: median focal error <= 2 %, normal <= 0.5 deg.")


def bench_speed() -> None:
    from cascalib.simulate import simulate

    scene = simulate("terrace", seed=0)
    print("\n## Speed: 3000 frames x 5 persons per camera (terrace tracks tiled)\n")
    print("(wall time depends on the load of the shared machine; CPU time is this process's)\n")
    print("| camera | detections | upright | wall s | CPU s |")
    print("|---|---|---|---|---|")
    for tr in scene.tracks:
        kp = tr.keypoints[:, :5]
        reps = int(np.ceil(3000 / kp.shape[0]))
        big = tr.with_(keypoints=np.concatenate([kp] * reps)[:3000], track_ids=None,
                       timestamps=None)
        t0, c0 = time.perf_counter(), time.process_time()
        res = calibrate_single_view(big, rng=0)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        print(f"| {tr.camera} | {big.n_detections} | {res.diagnostics['n_upright']} | "
              f"{dt:.2f} | {dc:.2f} |")


def bench_real(data: Path) -> None:
    from cascalib.formats import load_calibration, read_tracks, read_tracks_many

    print("\n## Real data (nearly degenerate: one person in one spot)\n")
    print("| data | camera | result | f ref | f err % | normal err deg | 95 % interval |")
    print("|---|---|---|---|---|---|---|")
    p2s = data / "pose2sim_demo"
    ref = load_calibration(p2s / "Calib_qualisys_converted_by_pose2sim.toml")
    for setup in ("single_person", "multi_person"):
        for i, cam in enumerate(ref.cameras, start=1):
            tr = read_tracks(p2s / setup / "pose" / f"cam0{i}_json", image_size=(1088, 1920))
            _real_row(f"pose2sim {setup}", tr, cam, normal=True)
    cal = load_calibration(data / "caliscope_4cam" / "config.toml")
    for tr, cam in zip(read_tracks_many(data / "caliscope_4cam" / "xy_HOLISTIC.csv"),
                       cal.cameras, strict=True):
        _real_row("caliscope (world = cam_1, no ground)", tr.with_(image_size=cam.image_size),
                  cam, normal=False)


def _real_row(label: str, tr, cam, *, normal: bool) -> None:
    try:
        res = calibrate_single_view(tr, rng=0)
        verdict = "estimate"
    except EstimationFailed as err:
        res = getattr(err, "partial", None)
        verdict = f"refused: {err.message}"
    if res is None:
        print(f"| {label} | {tr.camera} | {verdict} | {cam.focal:.0f} | | | |")
        return
    e = _camera_errors(res, cam)
    lo, hi = res.focal_interval
    nd = f"{e['N']:.1f}" if normal else "n/a"
    print(f"| {label} | {tr.camera} | {verdict} | {cam.focal:.0f} | {e['f']:+.1f} "
          f"(f={res.focal:.0f}) | {nd} | [{lo:.0f}, {hi:.0f}] |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="all",
                    choices=["protocol", "presets", "limits", "speed", "real", "all"])
    ap.add_argument("--trials", type=int, default=500)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--height-people", type=int, default=None,
                    help="run only the height sweep, with this many people")
    ap.add_argument("--duration", type=float, default=None,
                    help="scene length (s) of the presets part (default: each preset's own)")
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if args.part in ("protocol", "all"):
        bench_protocol(args.trials, args.height_people)
    if args.part in ("presets", "all"):
        bench_presets(args.seeds, args.duration)
    if args.part in ("limits", "all"):
        bench_limits(args.seeds)
    if args.part in ("speed", "all"):
        bench_speed()
    if args.part in ("real", "all"):
        bench_real(Path(args.data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
