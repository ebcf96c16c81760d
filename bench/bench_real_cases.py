"""The presets of what real recordings bring (gait, horizontal, short_clip, fisheye_webcam,
mixed_rates) through :func:`cascalib.calibrate`, one JSON line per preset and seed: the path
that ran (stage I + II-IV, or the multi-view start), errors against the simulator's truth, the
verdicts, wall seconds, or the stage's message where it refused.

Usage::

    python bench/bench_real_cases.py gait horizontal --seeds 0 1 2
    python bench/bench_real_cases.py mixed_rates --seeds 0 --set timing.fps=25,25,25,25
"""

from __future__ import annotations

import argparse
import json
import time

from cascalib.config import CalibrationConfig
from cascalib.metrics import compare_calibrations
from cascalib.pipeline import calibrate
from cascalib.simulate import simulate
from cascalib.stages.multiview_path import MultiviewInitial


def _value(text: str) -> object:
    """A --set value: comma-separated numbers are a tuple, a number is a float, else text."""
    try:
        if "," in text:
            return tuple(float(v) for v in text.split(","))
        return float(text)
    except ValueError:
        return text


def one(name: str, seed: int, overrides: dict[str, object], synchronized: bool) -> dict:
    scene = simulate(name, seed=seed, **overrides)
    t0 = time.perf_counter()
    row: dict[str, object] = {"preset": name, "seed": seed, **{k: str(v) for k, v in
                                                              overrides.items()}}
    try:
        res = calibrate(scene.tracks, CalibrationConfig(synchronized=synchronized))
    except Exception as err:  # noqa: BLE001 - a refusal is a row, not a crash
        row.update(failed=f"{type(err).__name__}: {err}", seconds=time.perf_counter() - t0)
        return row
    ground = "ground z=0" in res.calibration.world
    s = compare_calibrations(res.calibration, scene.truth, ground=ground).summary
    row.update(
        path="multiview" if isinstance(res.alignment, MultiviewInitial) else "stage I-IV",
        cameras=f"{len(res.calibration)}/{len(scene.truth)}",
        rot_pairs_median=round(s.pairwise_rotation_error_deg_median, 3),
        rot_pairs_max=round(s.pairwise_rotation_error_deg_max, 3),
        rot_median=round(s.rotation_error_deg_median, 3),
        rot_max=round(s.rotation_error_deg_max, 3),
        focal_pct_median=round(s.focal_error_pct_median, 2),
        focal_pct_max=round(s.focal_error_pct_max, 2),
        offset_frames_max=round(s.time_offset_error_frames_max, 3),
        rate_pct_max=round(s.time_rate_error_pct_max, 4),
        verdicts=[q.verdict for q in res.refinement.quality.values()],
        warnings=res.warnings(), seconds=round(time.perf_counter() - t0, 1))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("presets", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="a scene override, e.g. timing.fps=25,25,25,25")
    ap.add_argument("--synchronized", action="store_true")
    args = ap.parse_args()
    overrides = {k: _value(v) for k, v in (s.split("=", 1) for s in args.set)}
    for name in args.presets:
        for seed in args.seeds:
            print(json.dumps(one(name, seed, overrides, args.synchronized)), flush=True)


if __name__ == "__main__":
    main()
