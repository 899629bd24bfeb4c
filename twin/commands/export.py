"""``twin export CALIBRATION.json --out DIR``: the parameter table (CSV, markdown) and an MJCF of the
calibrated robot.

The MJCF comes from the world's generator (``twin.world.mjcf.robot_mjcf_xml``; a command is glue and may
call any layer): bodies on the kinematic chain of the *identified* robot and tool, the robot base at the MJCF
world origin, MuJoCo joint angles equal to the commanded joints, sites ``plate`` (tool frame) and
``sphere0..2``. Station frames are in calibration.json, not in the MJCF.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
from pathlib import Path


HELP = "write the calibrated robot as a parameter table (CSV, markdown) and an MJCF model"

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json")
    p.add_argument("--out", required=True, help="output folder (parameters.csv, parameters.md, robot.urdf, robot.xml)")


def mjcf(cal) -> str:
    """MJCF text of the calibrated robot (robot base frame = MJCF world; lengths [m], angles [rad]): the world's
    generator for the 6R arms with a plate of three spheres (so that it looks like the twin),
    :func:`twin.urdf.chain_mjcf_xml` otherwise (any chain, points or a tracker's pose)."""
    name = f"{cal.nominal.name}_calibrated_{cal.method}"
    if (cal.nominal.convention in ("mdh", "dh") and cal.nominal.n_joints == 6 and cal.spheres_tool.shape[0] == 3
            and cal.plate.sphere_diameter > 0):
        from ..world.mjcf import robot_mjcf_xml

        return robot_mjcf_xml(cal.robot, cal.spheres_tool, cal.plate.sphere_diameter, model_name=name)
    from ..urdf import chain_mjcf_xml

    return chain_mjcf_xml(cal.robot, model_name=name, tool_points=cal.spheres_tool)


def urdf(cal) -> str:
    """URDF text of the calibrated chain (robot base frame = root link ``base``), the tool and its points."""
    from ..urdf import chain_urdf_xml

    return chain_urdf_xml(cal.robot, robot_name=f"{cal.nominal.name}_calibrated_{cal.method}",
                          tool_points=cal.spheres_tool)


def run(args) -> int:
    from ..estimator import Calibration

    from ..estimator.plausibility import forced_reasons
    from . import warn_forced

    cal = Calibration.load(args.calibration)
    forced = forced_reasons(cal.details)
    warn_forced(args.calibration, forced)
    # every text first, then the files: an error leaves no partial output folder
    rows = cal.table()
    cols = ["name", "unit", "nominal", "identified", "deviation", "sd", "status"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([r["name"], r["unit"]] + [("" if not math.isfinite(r[c]) else f"{r[c]:.9g}") for c in cols[2:6]] + [r["status"]])
    md = [f"# Calibrated {cal.nominal.name} ({cal.nominal.convention}), method `{cal.method}`", ""]
    md += [f"**Forced** (`twin calibrate --force`): {r}" for r in forced] + ([""] if forced else [])
    md += ["| parameter | unit | nominal | identified | deviation | sd | status |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        sd = "" if not math.isfinite(r["sd"]) else f"{r['sd']:.3g}"
        md.append(f"| {r['name']} | {r['unit']} | {r['nominal']:.6f} | {r['identified']:.6f} | {r['deviation']:+.6f} | {sd} | {r['status']} |")
    if cal.combinations:
        md += ["", "Not identifiable from these data (held at nominal or estimated only in combination):", ""]
        md += [f"* {c.describe()}" for c in cal.combinations]
    xml = mjcf(cal)
    urdf_text = urdf(cal)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "parameters.csv").write_text(buf.getvalue())
    (out / "parameters.md").write_text("\n".join(md) + "\n")
    (out / "robot.xml").write_text(xml)
    (out / "robot.urdf").write_text(urdf_text)
    print(f"wrote {out / 'parameters.csv'}, {out / 'parameters.md'}, {out / 'robot.urdf'}, {out / 'robot.xml'}")
    return 0
