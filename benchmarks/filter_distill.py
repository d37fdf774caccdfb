"""How much of the look-ahead filter's racing mode a policy can learn to fly alone (distillation).

    .venv/bin/python benchmarks/filter_distill.py [--policy default] [--episodes 300]
        [--seed 7000] [--iterations 1] [--epochs 10] [--lr 3e-4] [--width 64]
        [--out runs/filter-distill] [--json PATH]

Each iteration flies ``--episodes`` random race layouts (ground truth, randomisation on, seeds
from ``--seed``) through the filter's racing mode (``--lookahead-race``) around the current
policy, records every observation with the action the filter flew, and fits the policy's network
to those actions (mean squared error, from the current weights; with ``--width`` above the
policy's, the new hidden units start with zero output, so the fit starts from the same function).
The fitted policy is written to ``OUT/iterN`` and flown on the 300 layouts of seed 5000 alone and
through the safety filter (``--lookahead``): finish rate and median lap. The next iteration
distils the filter around the fitted policy (expert iteration). Measured in
docs/history/policy.md (2026-12-07, a tenth session).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.callbacks import episode_success
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.export import ExportedPolicy, _write, load_policy
from icarus_vision.policy.features import obs_to_features
from icarus_vision.policy.lookahead import Lookahead, LookaheadConfig, racing
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


def collect(
    policy: ExportedPolicy, episodes: int, seed: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Observations and the racing filter's actions over ``episodes`` layouts, and its finish rate."""
    cfg = EnvConfig(
        random_tracks=True, num_gates=10, layout_difficulty=1.0,
        randomization=RandomizationConfig(enabled=True), observation=policy.observation,
    )  # fmt: skip
    env = BatchedRacingVecEnv(episodes, cfg)
    env.seed(seed)
    obs = env.reset()
    filt = Lookahead(policy, env.config, racing())
    over = np.zeros(episodes, dtype=bool)
    finished = np.zeros(episodes, dtype=bool)
    xs, ys = [], []
    while not over.all():
        live = ~over
        action = filt.act(env.core, env.state, obs, live)
        xs.append(obs[live].copy())
        ys.append(action[live].copy())
        obs, _, done, infos = env.step(action)
        for i in np.flatnonzero(done & live):
            finished[i] = episode_success(infos[i])
        over |= done
    return np.concatenate(xs), np.concatenate(ys), float(finished.mean())


def fit(
    policy: ExportedPolicy, obs: np.ndarray, actions: np.ndarray, *, epochs: int, lr: float,
    width: int, seed: int,
) -> tuple[dict, float]:  # fmt: skip
    """The policy's network fitted to ``actions`` (tensors for ``_write``) and the final loss."""
    torch.manual_seed(seed)
    feats = torch.tensor(obs_to_features(obs.astype(np.float32), policy.features))
    target = torch.tensor(actions, dtype=torch.float32)
    layers = []
    last = len(policy.weights) - 1
    for i, (w, b) in enumerate(policy.weights):
        n_out = w.shape[0] if i == last else max(width, w.shape[0])
        n_in = w.shape[1] if i == 0 else max(width, w.shape[1])
        weight = torch.zeros(n_out, n_in)
        if i < last:
            weight.normal_(0.0, 0.05)  # new units see the input; their outputs start at zero
        if i > 0:
            weight[:, w.shape[1] :] = 0.0  # nothing reads the new units yet: the same function
        weight[: w.shape[0], : w.shape[1]] = torch.tensor(w)
        bias = torch.zeros(n_out)
        bias[: w.shape[0]] = torch.tensor(b)
        layer = torch.nn.Linear(n_in, n_out)
        layer.weight.data, layer.bias.data = weight, bias
        layers.append(layer)
    opt = torch.optim.Adam([p for layer in layers for p in layer.parameters()], lr=lr)

    def forward(h: torch.Tensor) -> torch.Tensor:
        for layer in layers[:-1]:
            h = torch.tanh(layer(h))
        out = layers[-1](h)
        return out + (out.clamp(-1.0, 1.0) - out).detach()  # clipped as flown, gradient kept

    gen = torch.Generator().manual_seed(seed)
    loss_sum = 0.0
    for _ in range(epochs):
        loss_sum = 0.0
        for batch in torch.randperm(len(feats), generator=gen).split(4096):
            loss = ((forward(feats[batch]) - target[batch]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            loss_sum += loss.item() * len(batch)
    tensors = {}
    for i, layer in enumerate(layers):
        tensors[f"w{i}"] = layer.weight.detach().numpy().astype(np.float32)
        tensors[f"b{i}"] = layer.bias.detach().numpy().astype(np.float32)
    return tensors, loss_sum / len(feats)


def flown(policy: ExportedPolicy, lookahead: bool) -> dict:
    r = evaluate_policy(policy, None, episodes=300, num_gates=10, randomize=True, seed=5000,
                        difficulty=1.0, lookahead=LookaheadConfig() if lookahead else False)  # fmt: skip
    return {"finish": r["success_rate"], "median_lap_s": r["lap_time_s"]["median"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", default="default")
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=7000)
    ap.add_argument("--iterations", type=int, default=1)
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--out", default="runs/filter-distill")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    policy = resolve_policy(args.policy)
    rows = [{"policy": policy.name, "alone": flown(policy, False), "filter": flown(policy, True)}]
    print(json.dumps(rows[-1]), flush=True)
    for k in range(args.iterations):
        t0 = time.time()
        obs, actions, finish = collect(policy, args.episodes, args.seed + 1000 * k)
        tensors, loss = fit(policy, obs, actions, epochs=args.epochs, lr=args.lr,
                            width=args.width, seed=k)  # fmt: skip
        desc = json.loads(json.dumps(policy.desc))
        desc["hidden"] = [int(tensors[f"w{i}"].shape[0]) for i in range(len(tensors) // 2 - 1)]
        desc["meta"] = {**desc.get("meta", {}), "name": f"distilled-{k + 1}"}
        path = Path(args.out) / f"iter{k + 1}"
        _write(path, tensors, desc)
        policy = load_policy(path)
        rows.append({
            "policy": str(path), "samples": len(obs), "racing_filter_finish": finish,
            "loss": round(loss, 5), "alone": flown(policy, False), "filter": flown(policy, True),
            "wall_s": round(time.time() - t0, 1),
        })  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    if args.json:
        atomic_write_json(Path(args.json), rows)


if __name__ == "__main__":
    main()
