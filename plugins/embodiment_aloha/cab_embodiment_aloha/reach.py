"""Measure the TCP reach of the aloha_agilex arms over the task workspace (IK of an installed planner).

Usage: ``python -m cab_embodiment_aloha.reach [--step 0.05] [--zones main,shoes,dustbin] [--planner mplib]``

The planner is created through cab's registry and used through the planner contract
(:class:`cab_core.contracts.planner.Planner`: ``setup``, ``ik``, ``versions``), so this plugin declares no
dependency on any planner's package: ``--planner`` names any installed one (default ``mplib``, from
cab-planner-mplib; the figures in :mod:`.params` were measured with it).

Zones (world metres; from the tasks' placement ranges, FACTS B.6):
- ``main``: x in [-0.35, 0.35], y in [-0.25, 0.25], z in [0.75, 0.95] (objects on the 0.74 table);
- ``shoes``: place_dual_shoes, table lowered by 0.1: x in [-0.3, 0.3], y in [-0.2, 0.05], z in [0.66, 0.72];
- ``dustbin``: dump_bin_bigbin / put_bottles_dustbin (table shifted to x +0.3): the left arm above the
  big bin, x in [-0.55, -0.35], y in [-0.15, 0.15], z in [0.90, 1.10].

Approaches: ``top_down`` (approach -z; opening along world x or y) and ``forward`` (approach +y;
opening along world x or z). A point counts as reached by an arm if IK succeeds for either opening.
Reported: share reached by the left arm, the right arm, the nearer arm (x < 0 left, x > 0 right,
x = 0 either), either arm, and both arms.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cab_core.geometry import mat_to_quat
from cab_core.kits.registry import create_plugin

from .embodiment import build_spec

APPROACHES = {
    "top_down": ((0.0, 0.0, -1.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))),
    "forward": ((0.0, 1.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))),
}


def tcp_quat(approach, opening) -> np.ndarray:
    a = np.asarray(approach, float)
    o = np.asarray(opening, float)
    return mat_to_quat(np.stack([a, o, np.cross(a, o)], axis=1))


def _axis(lo: float, hi: float, step: float) -> np.ndarray:
    n = int(round((hi - lo) / step)) + 1
    return np.round(np.linspace(lo, hi, n), 4)


def zones(step: float) -> dict[str, dict]:
    zstep = max(step, 0.05)
    return {
        "main": {"x": _axis(-0.35, 0.35, step), "y": _axis(-0.25, 0.25, step),
                 "z": _axis(0.75, 0.95, zstep), "arms": ("left", "right")},
        "shoes": {"x": _axis(-0.30, 0.30, step), "y": _axis(-0.20, 0.05, step),
                  "z": _axis(0.66, 0.72, 0.06), "arms": ("left", "right")},
        "dustbin": {"x": _axis(-0.55, -0.35, step), "y": _axis(-0.15, 0.15, step),
                    "z": _axis(0.90, 1.10, 0.1), "arms": ("left",)},
    }


def measure(planner, spec, zone: dict, approach: str) -> dict:
    ap_axis, openings = APPROACHES[approach]
    quats = [tcp_quat(ap_axis, o) for o in openings]
    pts = [(x, y, z) for x in zone["x"] for y in zone["y"] for z in zone["z"]]
    reached = {arm: np.zeros(len(pts), dtype=bool) for arm in zone["arms"]}
    times = []
    for i, p in enumerate(pts):
        for arm in zone["arms"]:
            seed = np.asarray(spec.arms[arm].home_qpos, float)
            for q in quats:
                t0 = time.perf_counter()
                r = planner.ik(arm, np.concatenate([p, q]), seed)
                times.append(time.perf_counter() - t0)
                if r.ok:
                    reached[arm][i] = True
                    break
    xs = np.array([p[0] for p in pts])
    out = {"points": len(pts), "ik_ms_median": 1e3 * float(np.median(times)),
           "ik_ms_max": 1e3 * float(np.max(times))}
    for arm, r in reached.items():
        out[arm] = float(r.mean())
    if len(zone["arms"]) == 2:
        left, right = reached["left"], reached["right"]
        nearer = np.where(xs < 0, left, np.where(xs > 0, right, left | right))
        out["nearer"] = float(nearer.mean())
        out["either"] = float((left | right).mean())
        out["both"] = float((left & right).mean())
        out["missed_nearer"] = [tuple(float(v) for v in pts[i]) for i in np.where(~nearer)[0]]
    else:
        arm = zone["arms"][0]
        out["missed_nearer"] = [tuple(float(v) for v in pts[i]) for i in np.where(~reached[arm])[0]]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=0.05, help="grid step in x and y (m)")
    ap.add_argument("--zones", default="main,shoes,dustbin")
    ap.add_argument("--approaches", default="top_down,forward")
    ap.add_argument("--show-missed", action="store_true")
    ap.add_argument("--planner", default="mplib", help="an installed planner whose IK is measured (default mplib)")
    args = ap.parse_args(argv)

    spec = build_spec()
    planner = create_plugin("planners", args.planner, {})
    planner.setup(spec, 1.0 / 250.0)
    all_zones = zones(args.step)
    versions = ", ".join(f"{k} {v}" for k, v in sorted(planner.versions().items()))
    print(f"aloha_agilex reach (IK with the {args.planner} planner: {versions}), grid step {args.step} m")
    for zname in args.zones.split(","):
        zone = all_zones[zname]
        for appr in args.approaches.split(","):
            r = measure(planner, spec, zone, appr)
            cols = " ".join(f"{k}={100 * r[k]:5.1f}%" for k in ("left", "right", "nearer", "either", "both")
                            if k in r)
            print(f"{zname:8s} {appr:9s} n={r['points']:4d}  {cols}  "
                  f"ik {r['ik_ms_median']:.1f} ms median / {r['ik_ms_max']:.0f} ms max")
            if args.show_missed and r["missed_nearer"]:
                print("   missed (nearer arm):", r["missed_nearer"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
