"""``cascalib calibrate``: the whole cascade on one session, written to an output folder."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from cascalib.calibration_formats import WRITABLE
from cascalib.cli.progress import StageProgress

EXIT_REJECTED = 1
#: The formats ``--formats`` takes (the registry's writable ones).
FORMATS = WRITABLE


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "calibrate", help="calibrate and synchronise cameras from keypoint tracks",
        description="Each INPUT is one camera (a keypoint file, or a folder of per-frame JSON "
                    "files; the camera name is the file or folder name), a multi-camera file "
                    "(caliscope CSV), or one session manifest (TOML/JSON).")
    p.add_argument("inputs", nargs="+", metavar="INPUT", type=Path)
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUTDIR",
                   help="output folder (calibration.json, report.html, poses/)")
    add_camera_value_flags(p)
    p.add_argument("--height", type=float, default=None,
                   help="mean standing height of the people in metres (default 1.70)")
    p.add_argument("--known-intrinsics", type=Path, metavar="FILE",
                   help="calibration file (any supported format) whose cameras' intrinsics are "
                        "known and kept, matched by camera name")
    p.add_argument("--synchronized", action="store_true",
                   help="the cameras are already synchronised: estimate geometry only")
    p.add_argument("--formats", default="json", metavar="LIST",
                   help=f"comma-separated calibration formats to write ({','.join(FORMATS)})")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--reference-camera", metavar="NAME", help="camera defining world and clock")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="full configuration (JSON/TOML, keys of CalibrationConfig); flags win")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true",
                   help="print a machine-readable summary on stdout")
    p.set_defaults(run=run)


def add_camera_value_flags(p: argparse.ArgumentParser) -> None:
    """``--image-size`` / ``--fps`` / ``--skeleton``, shared with ``cascalib triangulate``."""
    p.add_argument("--image-size", action="append", metavar="WxH|NAME=WxH",
                   help="image size for every camera (1920x1080) or, repeated, NAME=WxH for one")
    p.add_argument("--fps", action="append", metavar="F|NAME=F",
                   help="frame rate for every camera (30) or, repeated, NAME=F for one")
    p.add_argument("--skeleton", help="keypoint skeleton where the file is ambiguous "
                                      "(coco17, body25, body25b, halpe26, ...)")


def build_config(args: argparse.Namespace):  # noqa: ANN201 - CalibrationConfig
    from cascalib.config import CalibrationConfig, KnownIntrinsics
    from cascalib.errors import InputError
    from cascalib.formats import load_calibration

    base = (CalibrationConfig.from_file(args.config).model_dump() if args.config else {})
    for key in ("height", "seed", "reference_camera"):
        if getattr(args, key) is not None:
            base[key] = getattr(args, key)
    if args.synchronized:
        base["synchronized"] = True
    if args.known_intrinsics is not None:
        known = load_calibration(args.known_intrinsics)
        base["known_intrinsics"] = {c.name: KnownIntrinsics(K=c.K.tolist(), dist=c.dist.tolist())
                                    for c in known}
    try:
        return CalibrationConfig.model_validate(base)
    except ValueError as exc:
        raise InputError(f"invalid configuration: {exc}", file=str(args.config or "")) from None


def file_stamps(folder: Path) -> dict[Path, int]:
    """Modification time (ns) of every file under ``folder`` (empty if it does not exist)."""
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def written_since(folder: Path, before: dict[Path, int]) -> list[Path]:
    """Files under ``folder`` that are new or changed since the :func:`file_stamps` ``before``."""
    now = file_stamps(folder)
    return sorted(p for p, t in now.items() if before.get(p) != t)


def files_line(folder: Path, files: list[Path]) -> str:
    """``a.json, b.toml, colmap/ (cameras.txt, images.txt), poses/ (poses.npz)``: files directly
    in ``folder`` first, then one group per subfolder."""
    top = [p.name for p in files if p.parent == folder]
    groups: dict[str, list[str]] = {}
    for p in files:
        if p.parent != folder:
            rel = p.relative_to(folder)
            groups.setdefault(rel.parts[0], []).append(str(Path(*rel.parts[1:])))
    return ", ".join(top + [f"{d}/ ({', '.join(names)})" for d, names in groups.items()])


def run(args: argparse.Namespace) -> int:
    started, t0 = time.time(), time.perf_counter()  # the bench adds the interpreter's start
    from cascalib.errors import InputError
    from cascalib.pipeline import calibrate
    from cascalib.session import resolve_session

    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputError(f"unknown format(s) {bad}; choose from {','.join(FORMATS)}",
                         field="formats")
    t1 = time.perf_counter()
    config = build_config(args)
    t2 = time.perf_counter()
    tracks, input_warnings = resolve_session(args.inputs, image_size=args.image_size,
                                             fps=args.fps, skeleton=args.skeleton)
    t3 = time.perf_counter()
    quiet = args.quiet or args.json
    with StageProgress(quiet=quiet) as progress:
        result = calibrate(tracks, config, progress=progress)
        t4 = time.perf_counter()
        progress("save", 0.0)
        before = file_stamps(args.output)
        written = result.save(args.output, formats=formats, report=not args.no_report)
        progress("save", 1.0)
    summary = result.summary() | {"outputs": {k: str(v) for k, v in written.items()}}
    # what the user waits for before the stages (checks: calibrate() outside its stages)
    summary["run_started_unix_s"] = started
    summary["input_timings_s"] = {"imports": t1 - t0, "configuration": t2 - t1,
                                  "reading": t3 - t2,
                                  "checks": t4 - t3 - sum(result.timings.values())}
    summary["warnings"] = input_warnings + summary["warnings"]
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        for cam in summary["cameras"]:
            c = cam["center_m"]
            print(f"{cam['name']:>10s}  f={cam['focal_px']:8.1f} px  "
                  f"C=({c[0]:6.2f}, {c[1]:6.2f}, {c[2]:5.2f}) m  offset={cam['time_offset']:8.2f}"
                  f"  rate={cam['time_rate']:.5f}  {cam['verdict']}: {cam['reason']}")
        for warning in summary["warnings"]:
            print(f"warning: {warning}")
        print(f"written to {args.output}/: "
              f"{files_line(args.output, written_since(args.output, before))}")
    if not result.accepted:
        failed = [c["name"] for c in summary["cameras"] if c["verdict"] == "failed"]
        print(f"cascalib calibrate: calibration rejected by the quality check: camera(s) "
              f"{', '.join(failed)} failed (see report.html)", file=sys.stderr)
        return EXIT_REJECTED
    return 0
