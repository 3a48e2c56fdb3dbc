"""One optimisation step of the CPU line-up's ACT: the train stage's loop against the stock one.

The policy is the demo's compact ACT (ResNet18 on a 32x32 head camera, one encoder and decoder
layer, chunk 25), randomly initialised from its config, on a random batch of the demo's shape
(timing does not depend on the values). Both ways run the same model, batch and AdamW in the
same process, interleaved over repeats; the best repeat of each is reported, per phase
(forward, backward, gradient clipping, optimiser) in CPU-milliseconds of this process:

- stock: lerobot's forward and torch's `clip_grad_norm_`, as the train stage ran them before;
- ours: the train stage's loop (`r2s_eval.policies.train`): the type's training speed-ups
  (for ACT, the one-pixel convolutions of ResNet's last stage as matrix products) and clipping
  that rescales only gradients over the limit.

Run: ``python benchmarks/bench_train_step.py [--batch 16] [--steps 20] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import time

import torch

from r2s_eval.config import candidate_config
from r2s_eval.policies.train import clip_gradients
from r2s_eval.policies.trained_config import make_lerobot_config
from r2s_eval.policies.types import policy_type
from r2s_eval.utils.numerics import deterministic_torch

CAMERA = "observation.images.head_left"
STATE, ACTION = "observation.state", "action"
PHASES = ("forward", "backward", "clip", "optimiser")


def build(batch: int):
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.modeling_act import ACTPolicy

    cfg = candidate_config("act", "demo")
    lr_cfg = make_lerobot_config(cfg)
    side = int(cfg["image_size"][0])
    lr_cfg.input_features = {
        STATE: PolicyFeature(type=FeatureType.STATE, shape=(14,)),
        CAMERA: PolicyFeature(type=FeatureType.VISUAL, shape=(3, side, side)),
    }
    lr_cfg.output_features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(14,))}
    torch.manual_seed(0)
    policy = ACTPolicy(lr_cfg)
    g = torch.Generator().manual_seed(1)
    chunk = int(cfg["chunk_size"])
    data = {
        STATE: torch.randn(batch, 14, generator=g),
        CAMERA: torch.randn(batch, 3, side, side, generator=g),
        ACTION: torch.randn(batch, chunk, 14, generator=g),
        "action_is_pad": torch.zeros(batch, chunk, dtype=torch.bool),
    }
    return cfg, lr_cfg, policy, data


def optimiser(lr_cfg, policy):
    preset = lr_cfg.get_optimizer_preset()
    return torch.optim.AdamW(policy.get_optim_params(), lr=preset.lr, betas=preset.betas, eps=preset.eps,
                             weight_decay=preset.weight_decay, fused=True)


def run(policy, optim, data, steps: int, ours: bool, max_norm: float) -> dict[str, float]:
    spent = dict.fromkeys(PHASES, 0.0)
    speedups = policy_type("act").training_speedups(policy) if ours else contextlib.nullcontext()
    with speedups:
        for _ in range(steps):
            t0 = time.process_time()
            loss, _ = policy.forward(dict(data))
            t1 = time.process_time()
            loss.backward()
            t2 = time.process_time()
            if ours:
                clip_gradients(policy, max_norm)
            else:
                torch.nn.utils.clip_grad_norm_(policy.parameters(), max_norm)
            t3 = time.process_time()
            optim.step()
            optim.zero_grad(set_to_none=True)
            t4 = time.process_time()
            for phase, (a, b) in zip(PHASES, ((t0, t1), (t1, t2), (t2, t3), (t3, t4))):
                spent[phase] += (b - a) * 1000 / steps
    return spent


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--batch", type=int, default=16, help="the demo's batch size")
    p.add_argument("--steps", type=int, default=20, help="optimisation steps per repeat and way")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch threads (the train stage's default: 1)")
    args = p.parse_args()
    deterministic_torch(args.threads)
    cfg, lr_cfg, policy, data = build(args.batch)
    max_norm = float(cfg["grad_clip_norm"])
    models = {way: copy.deepcopy(policy).train() for way in ("stock", "ours")}
    optims = {way: optimiser(lr_cfg, models[way]) for way in models}
    for way in models:  # warm-up: oneDNN's primitives, the allocator
        run(models[way], optims[way], data, 3, way == "ours", max_norm)
    best: dict[str, dict[str, float]] = {}
    for _ in range(args.repeats):
        for way in models:
            spent = run(models[way], optims[way], data, args.steps, way == "ours", max_norm)
            if way not in best or sum(spent.values()) < sum(best[way].values()):
                best[way] = spent
    print(f"ACT (demo config), batch {args.batch}, {args.threads} thread(s), {torch.backends.cpu.get_cpu_capability()} "
          f"kernels; CPU-ms per step, best of {args.repeats} x {args.steps} steps")
    print(f"{'phase':10s} {'stock':>8s} {'ours':>8s} {'ratio':>7s}")
    for phase in (*PHASES, "total"):
        old = sum(best["stock"].values()) if phase == "total" else best["stock"][phase]
        new = sum(best["ours"].values()) if phase == "total" else best["ours"][phase]
        print(f"{phase:10s} {old:8.1f} {new:8.1f} {old / max(new, 1e-9):6.2f}x")
    print(f"speed-up of a training step: {sum(best['stock'].values()) / sum(best['ours'].values()):.2f}x")


if __name__ == "__main__":
    main()
