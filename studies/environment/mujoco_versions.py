"""Which MuJoCo the lock pins, chosen by measurement: images and render cost of candidate versions.

For each candidate MuJoCo version, a throwaway virtual environment is built with uv from the lock's own
pins (``uv export``) with only ``mujoco`` replaced; ``probe.py`` renders the same stereo pairs in each
environment, in alternating rounds so that machine load hits all alike. Written: ``studies/environment/results/mujoco_versions.json``
(image hashes per version, seconds per pair per round, medians, provenance).

    .venv/bin/python studies/environment/mujoco_versions.py [--versions 4.0.0 3.3.7] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.benchio import provenance

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
UV = ROOT / ".tools" / "bin" / "uv"


def _env_for(version: str, scratch: Path) -> Path:
    """A virtual environment with the lock's pins and ``mujoco==version``; returns its python."""
    req = subprocess.run([str(UV), "export", "--frozen", "--all-extras", "--no-hashes", "--no-emit-project"],
                         cwd=ROOT, check=True, capture_output=True, text=True).stdout
    lines = [ln for ln in req.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    # mujoco 4 splits into mujoco-core / mujoco-studio: drop those pins and let the chosen mujoco bring its own
    lines = [ln for ln in lines if not re.match(r"^mujoco(-core|-studio)?==", ln)]
    lines.append(f"mujoco=={version}")
    venv = scratch / f"mujoco-{version}"
    (scratch / f"req-{version}.txt").write_text("\n".join(lines) + "\n")
    subprocess.run([str(UV), "venv", "-q", str(venv)], check=True)
    env = {**os.environ, "VIRTUAL_ENV": str(venv)}
    subprocess.run([str(UV), "pip", "install", "-q", "-r", str(scratch / f"req-{version}.txt")], check=True, env=env)
    subprocess.run([str(UV), "pip", "install", "-q", "--no-deps", "-e", str(ROOT)], check=True, env=env)
    return venv / "bin" / "python"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--versions", nargs="+", default=["4.0.0", "3.3.7"])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pairs", type=int, default=6)
    args = ap.parse_args()
    load0 = os.getloadavg()
    out: dict = {"versions": {}, "rounds": args.rounds, "pairs_per_round": args.pairs,
                 "setting": "World.render_pair, window_supersample 4, frame_subsample 2 (make run)"}
    with tempfile.TemporaryDirectory() as tmp:
        pythons = {v: _env_for(v, Path(tmp)) for v in args.versions}
        env = {**os.environ, "MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
        for r in range(args.rounds):
            for v, py in pythons.items():
                res = subprocess.run([str(py), str(HERE / "probe.py"), "--pairs", str(args.pairs)], check=True,
                                     capture_output=True, text=True, env=env)
                line = json.loads(res.stdout.strip().splitlines()[-1])
                if line["mujoco"] != v:
                    raise RuntimeError(f"environment for mujoco {v} imported mujoco {line['mujoco']}")
                d = out["versions"].setdefault(v, {"images_sha256": line["images_sha256"], "pair_s": []})
                if d["images_sha256"] != line["images_sha256"]:
                    raise RuntimeError(f"mujoco {v}: images differ between rounds")
                d["pair_s"].append([round(t, 4) for t in line["pair_s"]])
                d["load_1min"] = d.get("load_1min", []) + [round(os.getloadavg()[0], 2)]
    for d in out["versions"].values():
        flat = [t for rnd in d["pair_s"] for t in rnd]
        d["median_pair_s"] = round(statistics.median(flat), 4)
        d["round_medians_s"] = [round(statistics.median(rnd), 4) for rnd in d["pair_s"]]
    hashes = {d["images_sha256"] for d in out["versions"].values()}
    out["identical_images"] = len(hashes) == 1
    out["provenance"] = provenance(load0)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "mujoco_versions.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({v: d["median_pair_s"] for v, d in out["versions"].items()}), "identical images:",
          out["identical_images"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
