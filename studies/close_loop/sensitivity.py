"""`twin diagnose` on world effects of other shapes than its candidates, against the oracle.

The world's effects (written as world code: ``twin/world/effects_catalogue.py``, ``effects_shapes.py``), the
default stations' camera-visible poses, the world's true sphere centres plus N(0, sigma^2) per coordinate (no
rendering; the rendered runs are ``studies/close_loop/close_loop.py``). Every dataset records ``t_s`` *and* ``temp_c``
whatever the effect. Each effect's magnitude is scaled so that what it leaves after a perfect geometric-only
calibration (noise-free data, seed 0's poses) is ``--size`` noise sigmas.

Per case and seed: detected (structured); for catalogue effects *named* (the family listed) and *named with the
right joints/links* (the non-minor atoms of that family act exactly on the injected joints/links, and no other
family is listed); for effects outside the catalogue *traced* (a non-minor unnamed term, a listed change of its place
for a step, or a listed
alternative, at the expected place and channel); ``after/oracle``: validation RMS of the extended model over the
oracle's. The oracle is the true effect known exactly (the world's own centres with and without the effect) with
the geometry re-identified on the same noisy rows (``twin.evaluation.closeloop.oracle_delta_fit``). Clean seeds:
the false-alarm rate, and whether the extended model equals the geometric one.

    python studies/close_loop/sensitivity.py --seeds 20 --out studies/close_loop/results/close_loop_sensitivity.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the repository root: this checkout's `twin`

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
import numpy as np  # noqa: E402

from twin.benchio import command_line, provenance  # noqa: E402

from twin.diagnosis import diagnose
from twin.evaluation.closeloop import effect_delta, effect_size, oracle_delta_fit, plan_poses, synthetic_dataset
from twin.units import M_PER_MM
from twin.world import World, load_world_config
from twin.world.effects_catalogue import effect_from_spec

# name: (effect specs, scalable key path, expected). expected: ("named", family, {targets}) or
# ("traced", [(target, channel prefix), ...]) where target is the atom's target.
CASES = {
    "harmonic_j4_order2": ([{"name": "cyclic", "amplitude_deg": [0, 0, 0, 0.01, 0, 0], "order": 2.0, "phase_deg": 40.0}],
                           ("amplitude_deg",), ("named", "cyclic", {"theta4"})),
    "harmonic_motor_j5": ([{"name": "cyclic", "amplitude_deg": [0, 0, 0, 0, 0.004, 0], "order": 1.0, "phase_deg": 70.0,
                            "angle": "motor"}], ("amplitude_deg",), ("named", "cyclic", {"theta5"})),
    "backlash_j2_j3": ([{"name": "backlash", "half_clearance_deg": [0, 0.006, 0.006, 0, 0, 0]}],
                       ("half_clearance_deg",), ("named", "backlash", {"theta2", "theta3"})),
    "gear_ratio_j2": ([{"name": "gear_ratio", "ratio": [1, 1.0002, 1, 1, 1, 1]}], ("ratio",),
                      ("named", "gear_ratio", {"theta2"})),
    "coupling_5_6": ([{"name": "coupling", "coefficient": 0.0005}], ("coefficient",), ("named", "coupling", {"theta6"})),
    "compliance_payload": ([{"name": "compliance", "payload_kg": 3.0, "payload_com_mm": [0, 0, 60]}],
                           ("stiffness_nm_per_rad",), ("named", "compliance", None)),
    "growth_link_a3": ([{"name": "link_growth", "link": "a3", "temp_rise_k": 10.0, "tau_s": 1500.0}], ("alpha_per_k",),
                       ("named", "thermal", {"a3"})),
    "out_quadratic_j3": ([{"name": "joint_polynomial", "target_joint": 3, "source_joint": 3,
                           "coefficients_deg": [0.0, 0.01], "centre_deg": -10.0, "scale_deg": 45.0}],
                         ("coefficients_deg",), ("traced", [("theta3", "q3^")])),
    "out_cubic_j2_on_j4": ([{"name": "joint_polynomial", "target_joint": 4, "source_joint": 2,
                             "coefficients_deg": [0.0, 0.0, 0.01], "scale_deg": 45.0}],
                           ("coefficients_deg",), ("traced", [("theta4", "q2^")])),
    "out_coupling_2_to_3": ([{"name": "joint_polynomial", "target_joint": 3, "source_joint": 2, "coefficients_deg": [0.02]}],
                            ("coefficients_deg",), ("traced", [("theta3", "q2")])),
    "out_product_q2q3_on_j2": ([{"name": "joint_product", "target_joint": 2, "joints": [2, 3],
                                 "coefficient_deg_per_rad2": 0.02}], ("coefficient_deg_per_rad2",),
                               ("traced", [("theta2", "q2*q3")])),
    "out_base_slip": ([{"name": "base_shift", "at_s": 1500.0, "shift_mm": [0.01, -0.006, 0.008], "rotate_deg": [0, 0, 0.001]}],
                      ("shift_mm", "rotate_deg"), ("traced", [("base", "step(t_s")])),
    "out_plate_flex": ([{"name": "plate_flex", "k_mm_per_g": 0.01}], ("k_mm_per_g",),
                       ("traced", [("tool", "gravity_dir_flange_z"), ("d6", "gravity_dir_flange_z")])),
    "out_move_lag_j2": ([{"name": "move_lag", "lag_deg": [0, 0.006, 0, 0, 0, 0], "width_deg": 5.0}], ("lag_deg",),
                        ("traced", [("theta2", "tanh(last move j2")])),
}


def _scale(spec: dict, keys: tuple, m: float) -> dict:
    out = dict(spec)
    for k in keys:
        if k == "stiffness_nm_per_rad":
            base = out.get(k, [2e5, 2.5e5, 1.2e5, 2e4, 2e4, 1e4])
            out[k] = [s / m for s in base]
        elif k == "ratio":
            out[k] = [1 + (r - 1) * m for r in out[k]]
        elif k == "alpha_per_k":
            out[k] = out.get(k, 2.3e-5) * m
        elif isinstance(out[k], list):
            out[k] = [v * m for v in out[k]]
        else:
            out[k] = out[k] * m
    return out


def _verdict(res, expected) -> dict:
    atoms = [a for a in res.atoms if not a.get("minor")]
    kind = expected[0]
    if kind == "named":
        fam, targets = expected[1], expected[2]
        mine = {a["target"] for a in atoms if a["family"] == fam}
        named = fam in res.effects
        exact = named and set(res.effects) == {fam} and (targets is None or mine == targets)
        return {"named": bool(named), "named_exact": bool(exact), "traced": None}
    places = expected[1]
    alts = [(d["target"], d["channel"]) for d in res.alternatives]
    terms = [(a["target"], a["channel"]) for a in atoms if a["family"] == "unnamed"] + alts
    # a change at one moment (diagnosis.json `changes`) is a step of its place in time
    terms += [(c["target"], "step(") for c in res.changes if not c.get("minor")]
    traced = any(t == tgt and (ch.startswith(pre) or (ch == "step(" and pre.startswith("step(")))
                 for tgt, pre in places for t, ch in terms)
    return {"named": None, "named_exact": None, "traced": bool(traced)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--clean-seeds", type=int, default=20)
    ap.add_argument("--size", type=float, default=4.0, help="effect size after a perfect geometric fit [noise sigmas]")
    ap.add_argument("--sigma-mm", type=float, default=0.002, help="sphere-centre noise per coordinate [mm]")
    ap.add_argument("--per-station", type=int, default=40)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--world", default="experiments/world_default.toml", help="relative to the repository root")
    ap.add_argument("--out", default="studies/close_loop/results/close_loop_sensitivity.json",
                    help="relative to the repository root")
    args = ap.parse_args()
    load_start = os.getloadavg()
    sigma = args.sigma_mm * M_PER_MM
    world = World.from_config(load_world_config(ROOT / args.world))
    t0 = time.time()
    world.effects = []
    # plans depend on the stations and the seed, not on the effect: one per seed, shared by every case
    plans = {seed: plan_poses(world, args.per_station, seed=seed) for seed in range(max(args.seeds, args.clean_seeds) + 1)}
    out: dict = {"command": command_line("python studies/close_loop/sensitivity.py", [
        x for k, v in vars(args).items() for x in (f"--{k.replace('_', '-')}", str(v))]),
        "sigma_mm": args.sigma_mm, "per_station": args.per_station, "rows": int(len(plans[0].q)),
        "definition": __doc__.split("\n\n")[1] + " " + __doc__.split("\n\n")[2], "cases": {}}
    # clean: false alarms
    alarms = equal = 0
    for k in range(args.clean_seeds):
        ds, _ = synthetic_dataset(world, plans[k + 1], sigma=sigma, seed=2000 + k, record_temp=True)
        res = diagnose(ds)
        alarms += bool(res.structured)
        equal += res.after == res.before
    out["clean"] = {"seeds": args.clean_seeds, "alarms": alarms, "no_alarm_rate": 1 - alarms / max(args.clean_seeds, 1),
                    "after_equals_geometric": equal}
    print(f"clean: {alarms}/{args.clean_seeds} alarms", flush=True)
    for name in args.cases.split(","):
        specs, keys, expected = CASES[name]
        world.effects = [effect_from_spec(s) for s in specs]
        s0 = effect_size(world, plans[0], sigma, record_temp=True)
        m = args.size / s0 if s0 > 0 else 1.0
        specs_m = [_scale(s, keys, m) for s in specs]
        world.effects = [effect_from_spec(s) for s in specs_m]
        size = effect_size(world, plans[0], sigma, record_temp=True)
        rows = []
        for seed in range(args.seeds):
            plan = plans[seed + 1]
            ds, _ = synthetic_dataset(world, plan, sigma=sigma, seed=100 + seed, record_temp=True)
            t = time.time()
            res = diagnose(ds)
            dt = time.time() - t
            oracle = oracle_delta_fit(ds, effect_delta(world, plan)).after["position_mm"]["rms"]
            v = _verdict(res, expected)
            rows.append({"seed": seed, "structured": bool(res.structured), **v,
                         "after_over_oracle": res.after["position_mm"]["rms"] / oracle,
                         "before_over_oracle": res.before["position_mm"]["rms"] / oracle,
                         "explained_fraction": res.explained_fraction, "effects": list(res.effects),
                         "terms": [a["text"] for a in res.atoms if not a.get("minor")],
                         "alternatives": [d["alternative"] for d in res.alternatives], "diagnose_s": dt})
        ratio = np.array([r["after_over_oracle"] for r in rows])
        summ = {
            "kind": expected[0], "expected": expected[1] if expected[0] == "named" else expected[1],
            "expected_targets": sorted(expected[2]) if expected[0] == "named" and expected[2] else None,
            "specs": specs_m, "size_sigmas": size, "seeds": args.seeds,
            "detected": float(np.mean([r["structured"] for r in rows])),
            "named": None if expected[0] != "named" else float(np.mean([r["named"] for r in rows])),
            "named_exact": None if expected[0] != "named" else float(np.mean([r["named_exact"] for r in rows])),
            "traced": None if expected[0] != "traced" else float(np.mean([r["traced"] for r in rows])),
            "after_over_oracle": {"median": float(np.median(ratio)), "p90": float(np.quantile(ratio, 0.9)),
                                  "max": float(ratio.max())},
            "before_over_oracle_median": float(np.median([r["before_over_oracle"] for r in rows])),
            "per_seed": rows,
        }
        out["cases"][name] = summ
        print(f"{name:24s} size {size:4.1f}: detected {summ['detected']:.2f} named {summ['named']} exact "
              f"{summ['named_exact']} traced {summ['traced']} after/oracle median {summ['after_over_oracle']['median']:.3f} "
              f"max {summ['after_over_oracle']['max']:.3f}", flush=True)
    out["seconds"] = time.time() - t0
    out["provenance"] = provenance(load_start)
    p = ROOT / args.out
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(out, indent=1, default=float) + "\n")
    _table(out, p.with_suffix(".md"))
    _plot(out, p.with_suffix(".png"))
    return 0


def _table(out: dict, path: Path) -> None:
    lines = [f"# `twin diagnose` on world effects of new shapes ({out['cases'] and next(iter(out['cases'].values()))['seeds']} "
             f"seeds each, {out['rows']} rows, {out['sigma_mm']} mm noise; written by `{out['command']}`)", "",
             f"Clean: {out['clean']['alarms']} alarms in {out['clean']['seeds']} seeds "
             f"(no alarm {100 * out['clean']['no_alarm_rate']:.0f} %); extended = geometric in "
             f"{out['clean']['after_equals_geometric']}/{out['clean']['seeds']}.", "",
             "| case | kind | size [sigma] | detected | named | named, right joints/links | traced | after/oracle median | p90 | max | before/oracle |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    f = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
    for name, c in out["cases"].items():
        r = c["after_over_oracle"]
        lines.append(f"| {name} | {c['kind']} | {c['size_sigmas']:.1f} | {f(c['detected'])} | {f(c['named'])} | "
                     f"{f(c['named_exact'])} | {f(c['traced'])} | {r['median']:.3f} | {r['p90']:.3f} | {r['max']:.3f} | "
                     f"{c['before_over_oracle_median']:.2f} |")
    path.write_text("\n".join(lines) + "\n")


def _plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(out["cases"])
    fig, ax = plt.subplots(figsize=(11, 4.5))
    for i, n in enumerate(names):
        r = [s["after_over_oracle"] for s in out["cases"][n]["per_seed"]]
        ax.scatter(np.full(len(r), i) + np.random.default_rng(i).uniform(-0.15, 0.15, len(r)), r, s=10)
    ax.axhline(1.2, color="k", ls="--", lw=0.8, label="1.2x (catalogue target)")
    ax.axhline(1.5, color="grey", ls=":", lw=0.8, label="1.5x (outside-catalogue target)")
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=35, ha="right", fontsize=8)
    ax.set_ylabel("extended-model validation RMS / oracle")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
