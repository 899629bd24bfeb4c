"""Where `make run`'s render time goes, and what it was: a profile of one stereo pair at make run's setting, and
the same pairs timed with an earlier commit's code, back to back.

`make run` spends most of its campaign time rendering stereo pairs (section `campaign` of results/benchmark.json:
the phases). This profiles ``World.capture`` of ``--pairs`` visible configurations spread over the stations of
make run's world (experiments/separation.toml's ``[world]`` table) with cProfile on process CPU time (every
thread: llvmpipe's rasteriser threads are counted while the GL read-back waits for them) and writes the
``render_profile`` section: seconds per pair (CPU and wall), and the share of the pair's CPU time of each
function that takes >= 1 % of it (own time).

``--against REV``: the same pairs timed (experiments/time_pairs.py, no profiler) with the code and make run
config of commit REV (its tree extracted from git into a temporary folder, run with this environment's
packages) and with the current code, alternately, ``--rounds`` times each, each run a fresh process with its
load average: section ``render_profile.comparison``, medians and their ratio. The machine is shared: only runs
made back to back in the same conditions are compared.

    .venv/bin/python experiments/profile_render.py [--pairs 16] [--against 9b4e55f --rounds 3]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "experiments" / "separation.toml"


def _world_table(config_text: str) -> dict:
    raw = tomllib.loads(config_text)
    world = dict(raw["world"])
    world.setdefault("seed", raw.get("seed", 0))
    return world


def _profile(pairs: int) -> dict:
    from twin.runtime import set_process_defaults

    set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
    from twin.world import World

    world = _world_table(CONFIG.read_text())
    load0 = [round(x, 2) for x in os.getloadavg()]
    w = World.from_config({"world": world})
    n_st = len(w.station_names)
    qs = [(k, q) for k in range(n_st) for q in w.visible_configurations(k, -(-pairs // n_st), seed=0)][:pairs]
    w.capture(qs[0][1], qs[0][0], record=False, noise_seed=0)  # warm-up: renderer, textures
    prof = cProfile.Profile(time.process_time)
    c0, t0 = time.process_time(), time.perf_counter()
    prof.enable()
    for i, (k, q) in enumerate(qs):
        w.capture(q, k, record=False, noise_seed=1000 + i)
    prof.disable()
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    w.close()
    rows = []
    for (fname, line, func), (_, ncalls, tt, _, _) in pstats.Stats(prof).stats.items():
        share = tt / cpu
        if share >= 0.01:
            where = os.path.basename(fname) if fname.startswith(("/", ".")) else fname
            rows.append({"function": f"{where}:{line}({func})" if line else func,
                         "calls_per_pair": round(ncalls / len(qs), 2),
                         "own_cpu_s_per_pair": round(tt / len(qs), 4), "share": round(share, 3)})
    rows.sort(key=lambda r: -r["share"])
    return {"setting": world.get("render", {}), "pairs": len(qs), "pair_cpu_s": round(cpu / len(qs), 4),
            "pair_wall_s": round(wall / len(qs), 4), "functions": rows, "load_average_at_start": load0,
            "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
            "note": "cProfile on process CPU time (all threads) over the pairs, own time per function and its share "
                    "of the pairs' CPU time; pair_wall_s: the same pairs' wall time under the profiler"}


def _time_pairs(tree: Path, config: Path, pairs: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.setdefault("MUJOCO_GL", "egl")
    cmd = [sys.executable, str(ROOT / "experiments" / "time_pairs.py"), str(config), "--pairs", str(pairs)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compare(rev: str, rounds: int, pairs: int) -> dict:
    from twin.benchio import alternate_with_commit

    sha, head, runs = alternate_with_commit(
        rev, rounds, lambda tree, _: _time_pairs(tree, tree / "experiments" / "separation.toml", pairs), ROOT)

    def median(code: str, key: str) -> float:
        v = sorted(r[key] for r in runs if r["code"] == code)
        return round(v[len(v) // 2] if len(v) % 2 else 0.5 * (v[len(v) // 2 - 1] + v[len(v) // 2]), 4)

    med = {code: {k: median(code, k) for k in ("pair_cpu_s", "pair_wall_s")} for code in (sha, "current")}
    return {"against": sha, "current": head, "rounds": rounds, "pairs": pairs, "runs": runs, "median": med,
            "ratio_current_to_against": {k: round(med["current"][k] / med[sha][k], 3)
                                         for k in ("pair_cpu_s", "pair_wall_s")},
            "note": "experiments/time_pairs.py in a fresh process per run, each code with its own make run config "
                    "(experiments/separation.toml of that commit), alternating, the same pairs (seed 0 over the "
                    "stations); CPU time counts every thread"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--against", default=None, help="a commit to time back to back with the current code")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    if a.pairs < 1 or a.rounds < 1:
        raise SystemExit(f"--pairs and --rounds must be >= 1, got {a.pairs}, {a.rounds}")
    from twin.benchio import read_benchmark, update_benchmark_section

    data = _profile(a.pairs)
    for r in data["functions"]:
        print(f"{r['share']:6.1%}  {r['own_cpu_s_per_pair']:.4f} s  {r['function']}")
    print(f"pair: {data['pair_cpu_s']:.3f} s CPU, {data['pair_wall_s']:.3f} s wall (profiled)")
    if a.against:
        data["comparison"] = _compare(a.against, a.rounds, a.pairs)
        print(json.dumps(data["comparison"]["median"]), data["comparison"]["ratio_current_to_against"])
    else:
        earlier = read_benchmark().get("render_profile", {}).get("comparison")
        if earlier:
            data["comparison"] = earlier  # kept until the comparison is run again
    update_benchmark_section("render_profile", data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
