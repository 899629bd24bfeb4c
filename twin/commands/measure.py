"""``twin measure``: the instrument -> a dataset folder.

Two sources of images, one measurement path:

* ``twin measure IMAGES --out DATASET``: a folder of stereo pairs + board views (``docs/formats.md``,
  "Image folder"), from a real rig or written by the world;
* ``twin measure --render --out DATASET``: the twin renders the board views and the pairs in memory
  (``--world CONFIG.toml``, ``--joints JOINTS.csv`` or ``--poses N``); ``--keep-images DIR`` also writes
  them as an image folder. The truth of the rendered poses goes to a separate file (``--truth``).

Either way the rig is calibrated from the board views (never read from the world). With ``--render`` this is
the runner's measure stage (:func:`twin.runner.rendered.measure_rendered`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..units import MM_PER_M

HELP = "measure sphere centres in stereo image pairs (calibrating the rig from board views) -> dataset folder"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", type=Path, nargs="?", default=None,
                   help="image folder: rig.toml, joints.csv, board/, pairs/ (docs/formats.md); omit with --render")
    p.add_argument("--out", type=Path, required=True, help="dataset folder to write (poses.csv, dataset.toml)")
    p.add_argument("--calib", type=Path, default=None,
                   help="reuse this stereo_calibration.json instead of calibrating from board views")
    p.add_argument("--plate", type=Path, default=None,
                   help="TOML file with a [plate] table (sphere_diameter_mm, spheres_mm), e.g. a dataset.toml; "
                        "default: the twin's plate (twin.dataset.default_plate)")
    p.add_argument("--robot", default=None, help="robot name for dataset.toml (default: irb1200, or the world's)")
    p.add_argument("--no-bias-correction", action="store_true",
                   help="write ellipse centres instead of cone-corrected centres (to see the perspective bias)")
    p.add_argument("--provenance", default="", help="free text for dataset.toml")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    g = p.add_argument_group("rendering with the twin (--render)")
    g.add_argument("--render", action="store_true", help="render board views and pairs with the twin instead of reading IMAGES")
    g.add_argument("--world", type=Path, default=None, help="TOML with a [world] table (default: the built-in twin)")
    g.add_argument("--joints", type=Path, default=None, help="JOINTS.csv of commanded configurations to measure")
    g.add_argument("--poses", type=int, default=20,
                   help="without --joints: this many configurations that show the plate to both cameras (default 20)")
    g.add_argument("--station", type=int, default=0, help="without --joints: camera station index (default 0)")
    g.add_argument("--seed", type=int, default=0, help="seed of the generated configurations")
    g.add_argument("--board-views", type=int, default=None, help="board views to render (default: the world's)")
    g.add_argument("--keep-images", type=Path, default=None, help="also write the rendered image folder here")
    g.add_argument("--truth", type=Path, default=None,
                   help="truth file of the rendered poses (default: truth.json beside DATASET); only evaluation reads it")


def _progress(args):
    def cb(k, row, m=None):
        if not args.quiet and (row.status or k % 10 == 0):
            tail = f"  {row.status}" if row.status else ""
            print(f"pose {row.pose_id}: {'complete' if not row.status else 'partial'}{tail}", file=sys.stderr)

    return cb


def _report(summary) -> int:
    cal = summary.calibration
    print(f"stereo calibration: {cal.n_views_used} board views used, RMS {cal.rms_px:.3f} px "
          f"(left {cal.rms_left_px:.3f}, right {cal.rms_right_px:.3f}), baseline {cal.baseline * MM_PER_M:.2f} mm")
    for v in cal.views:
        if not v.used:
            print(f"  board view {v.name} rejected: {v.reason}")
    print(json.dumps(summary.to_dict(), indent=2))
    if summary.validation_error:
        print(f"twin measure: warning: the dataset does not validate: {summary.validation_error}", file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    from ..dataset import default_plate
    from ..instrument.folder import measure_folder, read_plate_toml

    if args.render:
        if args.images is not None:
            raise ValueError("images: give either an image folder or --render, not both")
        return _run_render(args)
    if args.images is None:
        raise ValueError("images: an image folder is required (or --render to let the twin render)")
    plate = read_plate_toml(args.plate) if args.plate else default_plate()
    summary = measure_folder(
        args.images, args.out, plate=plate, calib=args.calib, robot=args.robot or "irb1200",
        bias_correction=not args.no_bias_correction, provenance=args.provenance, on_row=_progress(args),
    )
    return _report(summary)


def _run_render(args: argparse.Namespace) -> int:
    """Render with the twin and measure: the runner's measure stage (``twin.runner.rendered``)."""
    from ..dataset import read_joints_csv
    from ..files import read_toml
    from ..instrument.folder import read_plate_toml
    from ..runner.rendered import measure_rendered
    from ..world import load_world_config

    world: dict = {}
    if args.world:
        load_world_config(args.world)  # a bad file or key is named here
        data = read_toml(args.world)
        world = data["world"] if isinstance(data.get("world"), dict) else data
    truth = args.truth or (Path(args.out).parent / "truth.json")
    summary = measure_rendered(
        world, args.out, joints=read_joints_csv(args.joints) if args.joints else None, poses=args.poses,
        station=args.station, seed=args.seed, plate=read_plate_toml(args.plate) if args.plate else None,
        calibration_file=args.calib, board_views=args.board_views, bias_correction=not args.no_bias_correction,
        keep_images=args.keep_images, truth=truth, robot=args.robot, provenance=args.provenance,
        on_row=_progress(args),
    )
    print(f"truth of the rendered poses: {truth}", file=sys.stderr)
    return _report(summary)
