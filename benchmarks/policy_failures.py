"""Where a policy fails on race layouts: the gate it was flying to, by the gate's shape and place.

    .venv/bin/python benchmarks/policy_failures.py [--policy default] [--episodes 300]
        [--seed 5000] [--gates 10] [--difficulty 1.0] [--no-randomize] [--lookahead]
        [--lookahead-race] [--keep-s S] [--json PATH]

Flies ``--episodes`` random race layouts (ground truth, randomisation on: the finish-rate setting of
``policy_speed.py``) and, for every gate the policy flew to, records whether it got through. Prints
the failure rate per gate (failures at a gate / gates attempted) by the gate's opening size, its
angle off the approach (the direction from the previous passage), the height change and the turn
it asks for, and how each failed episode ended (gate collision, ground, out of bounds, time); for
gate collisions, which gate was hit: the one being flown to, the one just passed (its frame clipped
on the way through), or another gate in the way (the gate nearest the drone's last position);
and by the crossing angle — between the drone's velocity and the gate's passage direction on the
step it passed the gate or hit the gate it was flying to — the failure rate at that gate.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from dataclasses import replace

import numpy as np

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.lookahead import Lookahead, LookaheadConfig, racing
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.rules import crossing_alignment
from icarus_vision.sim.vec_env import BatchedRacingVecEnv

BUCKETS = {
    "size_m": (0.8, 1.0, 1.2, 1.51),
    "off_approach_deg": (0, 15, 30, 45, 61),
    "climb_m": (-3.01, -1.5, -0.5, 0.5, 1.5, 3.01),
    "turn_deg": (0, 30, 60, 90, 180.1),
    "approach_m": (0, 3, 6, 10, 30),
}
CROSSING_DEG = (0, 15, 30, 45, 60, 75, 90.1)


def gate_properties(track) -> list[dict]:
    """Per passage: opening size, angle off the approach, climb, turn from the previous leg."""
    ps = track.passages
    start = np.array(track.start_pos, float)
    out = []
    prev_dir = np.array(
        [np.cos(np.radians(track.start_yaw_deg)), np.sin(np.radians(track.start_yaw_deg))]
    )
    prev = start
    for g in ps:
        p = np.array(g.pos, float)
        leg = p - prev
        d = leg[:2] / max(np.linalg.norm(leg[:2]), 1e-6)
        off = np.degrees(np.arccos(np.clip(d @ g.normal[:2], -1, 1)))
        turn = np.degrees(np.arccos(np.clip(d @ prev_dir, -1, 1)))
        out.append({
            "size_m": g.size, "off_approach_deg": off, "climb_m": leg[2],
            "turn_deg": turn, "approach_m": float(np.linalg.norm(leg)),
        })  # fmt: skip
        prev, prev_dir = p, g.normal[:2]
    return out


def gate_hit(track, passed: int, pos: np.ndarray) -> str:
    """Which gate a collision was with: the physical gate nearest ``pos`` (the drone's position
    at the start of the step it hit in), named by its role for the gate being flown to."""
    centres = np.array([g.pos for g in track.passages], float)
    nearest = centres[int(np.argmin(np.linalg.norm(centres - pos, axis=1)))]

    def same(k: int) -> bool:
        return 0 <= k < len(centres) and np.linalg.norm(centres[k] - nearest) < 0.05

    if same(passed):
        return "next"
    return "just passed" if same(passed - 1) else "other"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="default")
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--gates", type=int, default=10)
    ap.add_argument("--difficulty", type=float, default=1.0)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--lookahead",
        action="store_true",
        help="fly the policy through the look-ahead safety filter (policy/lookahead.py)",
    )
    ap.add_argument(
        "--lookahead-race", action="store_true",
        help="the filter in its racing mode (eval-policy --lookahead-race)",
    )  # fmt: skip
    ap.add_argument(
        "--keep-s", type=float, default=None,
        help="the filter's keep_s (0: predict every step; default: LookaheadConfig's)",
    )  # fmt: skip
    ap.add_argument(
        "--no-randomize", action="store_true",
        help="nominal quadrotor, no wind, gates where the layout puts them (what randomisation costs)",
    )  # fmt: skip
    a = ap.parse_args()

    policy = resolve_policy(a.policy)
    cfg = EnvConfig(
        random_tracks=True, num_gates=a.gates, layout_difficulty=a.difficulty,
        observation=policy.observation, randomization=RandomizationConfig(enabled=not a.no_randomize),
    )  # fmt: skip
    env = BatchedRacingVecEnv(a.episodes, cfg)
    env.seed(a.seed)
    obs = env.reset()
    a.lookahead = a.lookahead or a.lookahead_race
    config = racing() if a.lookahead_race else LookaheadConfig()
    if a.keep_s is not None:
        config = replace(config, keep_s=a.keep_s)
    pilot = Lookahead(policy, cfg, config) if a.lookahead else None
    tracks = list(env.core.tracks)
    results: list[dict | None] = [None] * a.episodes
    crossings: list[list[float]] = [[] for _ in range(a.episodes)]  # angle at each gate passed
    core, rows = env.core, np.arange(a.episodes)
    while any(r is None for r in results):
        last_pos, target = env.state.pos.copy(), core.target.copy()
        vel = env.state.vel.copy()
        angle = np.degrees(np.arccos(np.clip(
            crossing_alignment(np.zeros_like(vel), vel, core.g_yaw[rows, target]), -1.0, 1.0
        )))  # fmt: skip
        live = np.array([r is None for r in results])
        action = policy.act(obs) if pilot is None else pilot.act(core, env.state, obs, live)
        obs, _, done, infos = env.step(action)
        for i in np.flatnonzero((core.target != target) & ~done):
            if results[i] is None:
                crossings[i].append(angle[i])
        for i in np.flatnonzero(done):
            if results[i] is None:
                info = infos[i]
                if info["all_gates_passed"]:
                    crossings[i].append(angle[i])
                results[i] = {
                    "track": tracks[i], "passed": info["gates_passed"],
                    "total": info["gates_total"], "reason": info["crash_reason"] or "time",
                    "success": info["all_gates_passed"] and not info["crashed"],
                    "last_pos": last_pos[i], "crossings": crossings[i], "last_angle": angle[i],
                }  # fmt: skip
        tracks = list(env.core.tracks)

    attempted = defaultdict(lambda: defaultdict(int))
    failed = defaultdict(lambda: defaultdict(int))
    reasons = defaultdict(int)
    for r in results:
        props = gate_properties(r["track"])
        for k, p in enumerate(props[: r["passed"] + 1]):
            fail = (not r["success"]) and k == r["passed"]
            for name, edges in BUCKETS.items():
                b = int(
                    np.clip(np.searchsorted(edges, p[name], side="right") - 1, 0, len(edges) - 2)
                )
                label = f"{edges[b]:g}..{edges[b + 1]:g}"
                attempted[name][label] += 1
                failed[name][label] += fail
        if not r["success"]:
            reasons[r["reason"]] += 1
    hit = defaultdict(int)
    cross_ok, cross_hit = [], []
    for r in results:
        cross_ok += r["crossings"]
        if r["reason"] == "gate_collision":
            which = gate_hit(r["track"], r["passed"], r["last_pos"])
            hit[which] += 1
            if which == "next":
                cross_hit.append(r["last_angle"])
    n_ok = sum(r["success"] for r in results)
    filtered = " with the look-ahead filter" if a.lookahead else ""
    filtered += " (racing mode)" if a.lookahead_race else ""
    print(
        f"policy {a.policy}{filtered}: {n_ok}/{a.episodes} finished ({100 * n_ok / a.episodes:.1f} %)"
    )
    print("failed episodes by ending:", dict(reasons))
    print("gate collisions by the gate hit:", dict(hit))
    report = {
        "finished": n_ok, "episodes": a.episodes, "lookahead": a.lookahead,
        "lookahead_race": a.lookahead_race, "endings": dict(reasons),
        "gate_hit": dict(hit), "per_gate": {},
    }  # fmt: skip
    for name in BUCKETS:
        print(f"\n{name}: failure per gate attempted")
        rows = {}
        for label in attempted[name]:
            n, f = attempted[name][label], failed[name][label]
            rows[label] = {"attempted": n, "failed": f, "rate": f / n}
            print(f"  {label:>12}: {f:4d} / {n:5d} = {100 * f / n:5.1f} %")
        report["per_gate"][name] = rows
    print("\ncrossing angle (velocity to passage direction): next-gate collisions / attempts")
    n_ok, _ = np.histogram(cross_ok, CROSSING_DEG)
    n_hit, _ = np.histogram(cross_hit, CROSSING_DEG)
    report["crossing_deg"] = {}
    for lo, hi, ok, f in zip(CROSSING_DEG[:-1], CROSSING_DEG[1:], n_ok, n_hit, strict=True):
        n = int(ok + f)
        label = f"{lo:g}..{hi:g}"
        report["crossing_deg"][label] = {"attempted": n, "failed": int(f), "rate": f / max(n, 1)}
        print(f"  {label:>12}: {f:4d} / {n:5d} = {100 * f / max(n, 1):5.1f} %")
    if a.json:
        atomic_write_json(a.json, report)


if __name__ == "__main__":
    main()
