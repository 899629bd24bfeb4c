"""``twin render CONFIG --out DIR``: build the twin from a world config and render an image folder.

Writes ``DIR/images/`` (the image folder of ``docs/formats.md``: rig.toml, joints.csv, board/, pairs/),
``DIR/truth.json`` (for evaluation only) and ``DIR/mjcf/twin.xml`` (the generated MJCF with its textures).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HELP = "Render stereo image pairs and calibration-board views from the MuJoCo twin (world config -> image folder)."


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="TOML file with a [world] table (e.g. experiments/world_default.toml)")
    p.add_argument("--out", required=True, help="output folder (images/, truth.json, mjcf/)")
    p.add_argument("--joints", help="JOINTS.csv of commanded configurations (deg; optional station, t_s, temp_c)")
    p.add_argument("--per-station", type=int, default=3,
                   help="without --joints: visible configurations rendered at every station (default 3)")
    p.add_argument("--board-views", type=int, default=None, help="board views (default: the config's board.views)")
    p.add_argument("--scale", type=float, default=None, help="override render.scale (e.g. 0.25 for a quick look)")
    p.add_argument("--noise", type=float, default=None, help="override render.noise_sigma [grey levels]")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampled configurations and board poses")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    from twin.dataset import read_joints_csv
    from twin.world import World
    from twin.world.config import load_world_config
    from twin.world.effects import EffectContext

    cfg = load_world_config(args.config)
    if args.scale is not None or args.noise is not None:
        from dataclasses import replace

        render = cfg.render
        if args.scale is not None:
            if not 0 < args.scale <= 1:
                raise ValueError(f"--scale must be in (0, 1], got {args.scale}")
            render = replace(render, scale=float(args.scale))
        if args.noise is not None:
            if args.noise < 0:
                raise ValueError(f"--noise must be >= 0, got {args.noise}")
            render = replace(render, noise_sigma=float(args.noise))
        cfg = replace(cfg, render=render)
    out = Path(args.out)
    t0 = time.perf_counter()

    def progress(kind: str, k: int, n: int) -> None:
        if not args.quiet:
            print(f"  {kind} {k + 1}/{n}  ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)

    with World(cfg) as world:
        world.write_mjcf(out / "mjcf")
        kw: dict = {}
        if args.joints:
            joints = read_joints_csv(args.joints)
            kw["q_cmd"] = joints.q
            kw["pose_ids"] = joints.pose_id.tolist()
            kw["stations"] = joints.station.tolist() if joints.station is not None else None
            if joints.t_s is not None or joints.temp_c is not None:
                n = len(joints.pose_id)
                kw["contexts"] = [
                    EffectContext(
                        t_s=float(joints.t_s[k]) if joints.t_s is not None else 0.0,
                        temp_c=float(joints.temp_c[k]) if joints.temp_c is not None else 20.0,
                        pose_index=k,
                        station=world.station_index(kw["stations"][k]) if kw["stations"] is not None else 0,
                    )
                    for k in range(n)
                ]
        else:
            kw["per_station"] = args.per_station
        summary = world.write_image_folder(out / "images", board_views=args.board_views, seed=args.seed,
                                           callback=progress, **kw)
        world.write_truth(out / "truth.json")
    if not args.quiet:
        print(f"wrote {summary['pairs']} pairs and {summary['board_views']} board views to {out / 'images'}; "
              f"truth in {out / 'truth.json'} ({time.perf_counter() - t0:.1f} s)")
    return 0
