"""``cascalib simulate``: write a simulated multi-camera scene with its ground truth.

Writes ``OUT/tracks/<camera>.*`` (detections in the chosen keypoint format),
``OUT/calibration.json`` (the true cameras, with time offsets and rates), ``OUT/truth.npz``
(heights, ground plane, 3D joints) and ``OUT/scene.json`` (configuration and seed); with
``--plot`` also ``OUT/scene.png``. ``--list`` prints the presets.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cascalib.errors import InputError
from cascalib.formats.keypoints import FORMATS


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("simulate", help="write a simulated scene (detections + ground truth)",
                       description=__doc__)
    p.add_argument("--preset", default="terrace", help="scene preset (see --list)")
    p.add_argument("--config", type=Path, default=None,
                   help="JSON file with a full SceneConfig (instead of --preset)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--output", type=Path, help="output folder")
    p.add_argument("--format", default="native-json", choices=sorted(FORMATS),
                   help="keypoint file format (default native-json)")
    p.add_argument("--persons", type=int, default=None, help="override the number of persons")
    p.add_argument("--cameras", type=int, default=None, help="override the number of cameras")
    p.add_argument("--duration", type=float, default=None, help="override the length (s)")
    p.add_argument("--skeleton", default=None, help="skeleton of the detections")
    p.add_argument("--plot", action="store_true", help="also write OUT/scene.png")
    p.add_argument("--plot-camera", default=None, help="camera shown in the plot")
    p.add_argument("--list", action="store_true", help="list the presets and exit")
    p.set_defaults(run=run)


def _overrides(args: argparse.Namespace) -> dict[str, object]:
    out: dict[str, object] = {}
    if args.persons is not None:
        out["people.n_persons"] = args.persons
    if args.cameras is not None:
        out["rig.n_cameras"] = args.cameras
    if args.duration is not None:
        out["duration_s"] = args.duration
    if args.skeleton is not None:
        out["skeleton"] = args.skeleton
    return out


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from cascalib.simulate import PRESETS, SceneConfig, simulate

    if args.list:
        for name, cfg in PRESETS.items():
            print(f"{name:18s} {cfg.description}")
        return 0
    if args.output is None:
        raise InputError("give an output folder with -o OUT", field="output")
    try:
        if args.config is not None:
            config = SceneConfig.model_validate_json(args.config.read_text())
        else:
            config = args.preset
        scene = simulate(config, seed=args.seed, **_overrides(args))
    except (ValidationError, OSError) as exc:
        raise InputError(f"invalid scene configuration: {exc}",
                         file=None if args.config is None else str(args.config)) from None
    scene.save(args.output, args.format)
    if args.plot:
        from cascalib.simulate.plot import plot_scene

        plot_scene(scene, args.output / "scene.png", camera=args.plot_camera)
    print(json.dumps({"output": str(args.output), "seed": args.seed,
                      "cameras": [{"name": c.name, "size": list(c.image_size), "fps": c.fps,
                                   "time_offset": round(c.time_offset, 3),
                                   "time_rate": round(c.time_rate, 6),
                                   "frames": t.n_frames}
                                  for c, t in zip(scene.truth, scene.tracks, strict=True)],
                      "heights": [round(float(h), 3) for h in scene.heights]}, indent=1))
    return 0
