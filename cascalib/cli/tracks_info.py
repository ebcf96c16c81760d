"""``cascalib tracks-info PATH...``: what keypoint files hold, per camera.

Prints, per camera: format, skeleton, frames, persons, detections, image size, frame rate and
whether capture timestamps are present. ``--json`` prints the same as one JSON object.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from cascalib.formats.keypoints import FORMATS, detect_format, read_tracks_many
from cascalib.tracks import Tracks


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("tracks-info", help="summarise keypoint files (format, skeleton, frames)",
                       description=__doc__)
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="keypoint file or OpenPose folder (one or more)")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="input format (default: detected from the content)")
    p.add_argument("--skeleton", default=None, help="skeleton name where ambiguous")
    p.add_argument("--image-size", action="append", default=None, metavar="[CAM=]WxH",
                   help="image size for formats that do not store it (repeat per camera)")
    p.add_argument("--fps", action="append", default=None, metavar="[CAM=]FPS",
                   help="frame rate if not stored (repeat per camera)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(run=run)


def summary(tracks: Tracks, fmt: str) -> dict[str, Any]:
    """The facts ``tracks-info`` prints for one camera."""
    return {"camera": tracks.camera, "format": fmt, "skeleton": tracks.skeleton.name,
            "frames": tracks.n_frames, "persons": tracks.n_persons,
            "detections": tracks.n_detections,
            "image_size": None if tracks.image_size is None else list(tracks.image_size),
            "fps": tracks.fps, "timestamps": tracks.timestamps is not None,
            "track_ids": tracks.track_ids is not None, "source": tracks.source}


def per_camera(values: list[str] | None) -> dict[str, Any] | None:
    """``["1920x1080", "cam2=1280x720"]`` -> ``{"*": "1920x1080", "cam2": "1280x720"}`` (the
    readers parse and check the strings)."""
    if not values:
        return None
    out = {}
    for v in values:
        name, _, value = v.rpartition("=")
        out[name.strip() or "*"] = value.strip()
    return out


def run(args: argparse.Namespace) -> int:
    rows = []
    for path in args.paths:
        fmt = args.format or detect_format(path)
        for t in read_tracks_many(path, skeleton=args.skeleton,
                                  image_size=per_camera(args.image_size),
                                  fps=per_camera(args.fps), format=fmt):
            rows.append(summary(t, fmt))
    if args.json:
        print(json.dumps({"ok": True, "cameras": rows}, indent=2))
        return 0
    head = ("camera", "format", "skeleton", "frames", "persons", "detections", "image", "fps",
            "timestamps")
    table = [head] + [(r["camera"], r["format"], r["skeleton"], str(r["frames"]),
                       str(r["persons"]), str(r["detections"]),
                       "x".join(map(str, r["image_size"])) if r["image_size"] else "?",
                       f"{r['fps']:g}" if r["fps"] else "?",
                       "yes" if r["timestamps"] else "no") for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(head))]
    for row in table:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)).rstrip())
    return 0
