"""``cascalib triangulate --calibration FILE INPUT...``: 3D poses of a new recording of a rig."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cascalib.cli.calibrate import add_camera_value_flags
from cascalib.cli.progress import StageProgress

POSE_FORMATS = ("npz", "json", "trc", "c3d")


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "triangulate", help="3D poses from keypoint tracks and an existing calibration",
        description="Triangulate every frame of a recording made with an already calibrated "
                    "rig. Each INPUT is one camera, named like the calibration's cameras (the "
                    "file or folder name), a multi-camera file, or a session manifest. The "
                    "calibration's time offsets and rates are used as they are (cameras started "
                    "together, or hardware-synchronised) unless --resync estimates new ones "
                    "for this recording.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", type=Path)
    p.add_argument("--calibration", required=True, type=Path, metavar="FILE",
                   help="calibration of the rig (any supported format)")
    p.add_argument("--from", dest="from_format", metavar="FMT",
                   help="format of the calibration file (default: from its name and content)")
    p.add_argument("-o", "--output", type=Path, default=Path("poses"), metavar="OUTDIR",
                   help="output folder (default ./poses)")
    add_camera_value_flags(p)
    p.add_argument("--height", type=float, default=1.70,
                   help="mean standing height of the people in metres, for the association")
    p.add_argument("--resync", action="store_true",
                   help="estimate this recording's time offsets and rates (unsynchronised "
                        "cameras started anew); the geometry is kept. Writes "
                        "calibration_resync.json beside the poses")
    p.add_argument("--formats", default="npz,json,trc,c3d", metavar="LIST",
                   help=f"pose files to write ({','.join(POSE_FORMATS)}; c3d needs ezc3d)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true",
                   help="print a machine-readable summary on stdout")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from cascalib.errors import InputError
    from cascalib.formats import load_calibration
    from cascalib.session import load_session
    from cascalib.stages.reconstruct import match_calibration, triangulate_poses

    formats = tuple(f.strip() for f in args.formats.split(",") if f.strip())
    bad = [f for f in formats if f not in POSE_FORMATS]
    if bad:
        raise InputError(f"unknown pose format(s) {bad}; choose from {','.join(POSE_FORMATS)}",
                         field="formats")
    calibration = load_calibration(args.calibration, format=args.from_format)
    tracks = load_session(args.inputs, image_size=args.image_size, fps=args.fps,
                          skeleton=args.skeleton)
    # the calibration knows each camera's image size: tracks need not repeat it
    sizes = {c.name: c.image_size for c in calibration}
    tracks = [t if t.image_size or sizes.get(t.camera) is None
              else t.with_(image_size=sizes[t.camera]) for t in tracks]
    calibration = match_calibration(tracks, calibration)  # the cameras this recording has
    with StageProgress(quiet=args.quiet or args.json) as progress:
        if args.resync:
            from cascalib.formats import save_calibration
            from cascalib.stages.resync import resynchronize

            progress("sync", 0.0)
            calibration = resynchronize(tracks, calibration, height=args.height)
            progress("sync", 1.0)
            args.output.mkdir(parents=True, exist_ok=True)
            save_calibration(calibration, args.output / "calibration_resync.json", "json")
        progress("triangulate", 0.0)
        poses = triangulate_poses(tracks, calibration, height=args.height)
        progress("triangulate", 1.0)
    written = poses.save(args.output, formats=formats)
    seen = np.asarray(np.isfinite(poses.joints[..., 0]).any(axis=-1))
    summary = {
        "ok": True, "calibration": str(args.calibration),
        "frames": int(poses.joints.shape[0]), "frames_with_persons": int(seen.any(1).sum()),
        "max_persons": int(seen.sum(1).max()) if seen.size else 0,
        "person_tracks": len(poses.person_tracks()),
        "median_reprojection_px": (float(np.nanmedian(poses.residuals))
                                   if poses.residuals is not None and
                                   np.isfinite(poses.residuals).any() else None),
        "outputs": [str(p) for p in written],
        "time_offsets": {c.name: c.time_offset for c in calibration},
        "time_rates": {c.name: c.time_rate for c in calibration},
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        print(f"{summary['frames_with_persons']} of {summary['frames']} reference frames with "
              f"persons (at most {summary['max_persons']} at once, "
              f"{summary['person_tracks']} person tracks), median reprojection error "
              f"{summary['median_reprojection_px'] or float('nan'):.2f} px; "
              f"written to {args.output}/")
    return 0
