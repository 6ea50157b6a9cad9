"""`walkcap calibrate`: estimate the camera mounting from standing on level ground.

The subject stands still on open level floor, camera unobstructed, for a few seconds
(capture.labtools.mounting collects and estimates). The command prints old -> new and
writes [mounting] to the configuration file; it refuses, writing nothing, when the floor
is not found or the subject moved.
"""

from __future__ import annotations

import sys

HELP = "estimate the camera mounting from standing on level ground"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--seconds",
        type=float,
        default=3.0,
        metavar="S",
        help="how long to collect while the subject stands still (default 3)",
    )
    parser.add_argument(
        "--write",
        metavar="PATH",
        help="configuration file to write [mounting] to (default: the "
        "configuration read, else ./walkcap.toml)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="estimate and show the result, write nothing"
    )
    parser.add_argument(
        "--json", action="store_true", help="print the result as JSON instead of the table"
    )


def run(args, config) -> int:
    from capture.labtools.mounting import calibrate, current_mounting, write_mounting
    from inference.calibration import CalibrationError

    if not args.seconds > 0:
        raise CalibrationError(f"--seconds must be positive, got {args.seconds:g}")
    print(
        f"stand still on level ground, camera unobstructed: collecting {args.seconds:g} s ...",
        flush=True,
        file=sys.stderr if args.json else sys.stdout,  # stdout is the JSON's
    )
    result = calibrate(config, args.seconds)
    current = current_mounting(config)
    if args.json:
        return _json_result(args, config, result, current)
    print(
        f"frames: {result.frames_used} of {result.frames_total} show the floor; "
        f"floor inliers {100 * result.inlier_fraction:.0f}%, "
        f"plane RMS {1000 * result.plane_rms_m:.1f} mm, "
        f"camera height {result.camera_height_m:.3f} m"
    )
    if not result.ok:
        raise CalibrationError(f"calibration refused, nothing written: {result.problem}")
    print(f"fit residual {result.residual_deg:.2f} deg, thigh motion {result.motion_deg:.2f} deg")
    print(f"roll   {current[0]:+7.2f} -> {result.roll_deg:+7.2f} deg")
    print(f"pitch  {current[1]:+7.2f} -> {result.pitch_deg:+7.2f} deg")
    print(f"yaw    {current[2]:+7.2f}    (kept: not observable from a floor)")
    if args.dry_run:
        print("dry run: nothing written")
        return 0

    path = write_mounting(config, result, args.write)
    print(f"wrote [mounting] to {path}")
    return 0


def _json_result(args, config, result, current) -> int:
    import dataclasses
    import json

    from capture.labtools.mounting import write_mounting
    from capture.recording.topics import jsonable
    from inference.calibration import CalibrationError

    data = {k: v for k, v in dataclasses.asdict(result).items() if k != "per_frame"}
    data["ok"] = result.ok
    data["current"] = {"roll_deg": current[0], "pitch_deg": current[1], "yaw_deg": current[2]}
    data["written"] = None
    if result.ok and not args.dry_run:
        data["written"] = str(write_mounting(config, result, args.write))
    print(json.dumps(jsonable(data), indent=2))
    if not result.ok:
        raise CalibrationError(f"calibration refused, nothing written: {result.problem}")
    return 0
