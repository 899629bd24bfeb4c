"""``twin measure``: the instrument on a folder of stereo image pairs + board views -> a dataset folder."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = "measure sphere centres in stereo image pairs (calibrating the rig from board views) -> dataset folder"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", type=Path, help="image folder: rig.toml, joints.csv, board/, pairs/ (docs/formats.md)")
    p.add_argument("--out", type=Path, required=True, help="dataset folder to write (poses.csv, dataset.toml)")
    p.add_argument("--calib", type=Path, default=None,
                   help="reuse this stereo_calibration.json instead of calibrating from IMAGES/board/")
    p.add_argument("--plate", type=Path, default=None,
                   help="TOML file with a [plate] table (sphere_diameter_mm, spheres_mm), e.g. a dataset.toml; "
                        "default: the twin's plate (twin.dataset.default_plate)")
    p.add_argument("--robot", default="irb1200", help="robot name written to dataset.toml (default: irb1200)")
    p.add_argument("--no-bias-correction", action="store_true",
                   help="write ellipse centres instead of cone-corrected centres (to see the perspective bias)")
    p.add_argument("--provenance", default="", help="free text for dataset.toml")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    from ..dataset import default_plate
    from ..instrument.folder import measure_folder, read_plate_toml

    plate = read_plate_toml(args.plate) if args.plate else default_plate()

    def progress(k, row, m):
        if not args.quiet and (row.status or k % 10 == 0):
            tail = f"  {row.status}" if row.status else ""
            print(f"pose {row.pose_id}: {'complete' if not row.status else 'partial'}{tail}", file=sys.stderr)

    summary = measure_folder(
        args.images,
        args.out,
        plate=plate,
        calib=args.calib,
        robot=args.robot,
        bias_correction=not args.no_bias_correction,
        provenance=args.provenance,
        on_row=progress,
    )
    cal = summary.calibration
    rejected = [v for v in cal.views if not v.used]
    print(f"stereo calibration: {cal.n_views_used} board views used, RMS {cal.rms_px:.3f} px "
          f"(left {cal.rms_left_px:.3f}, right {cal.rms_right_px:.3f}), baseline {cal.baseline * 1e3:.2f} mm")
    for v in rejected:
        print(f"  board view {v.name} rejected: {v.reason}")
    print(json.dumps(summary.to_dict(), indent=2))
    if summary.validation_error:
        print(f"twin measure: warning: the dataset does not validate: {summary.validation_error}", file=sys.stderr)
        return 1
    return 0
