"""Batched policy inference: one model call for N episodes' observations vs N single calls.

The policy is the CPU line-up's compact ACT (ResNet18, 32x32 head camera, chunk 25), randomly
initialised from its config (timing does not depend on the weights), driven through the same
`LeRobotPolicy.predict_chunks` the rollout stage uses. Both ways run in the same process and
interleave over repeats; the best repeat of each is reported.

An episode of `--steps` control steps at execute-5 needs steps/5 chunk queries; episodes per
second is queries per second divided by that.

Run: ``python benchmarks/bench_policy_batch.py [--batch 8] [--repeats 5] [--threads 1]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from r2s_eval.policies import LeRobotPolicy
from r2s_eval.config import candidate_config
from r2s_eval.policies.trained_config import make_lerobot_config
from r2s_eval.utils.numerics import deterministic_torch

CAMERA = "observation.images.head_left"


def build_policy(image_hw: int) -> LeRobotPolicy:
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.processor import ImageCropResizeProcessorStep, NormalizerProcessorStep

    cfg = candidate_config("act", "demo")
    lr_cfg = make_lerobot_config(cfg)
    lr_cfg.input_features = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(14,)),
        CAMERA: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_hw, image_hw)),
    }
    lr_cfg.output_features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(14,))}
    stats = {
        "observation.state": {"mean": np.zeros(14), "std": np.ones(14), "min": -np.ones(14), "max": np.ones(14)},
        "action": {"mean": np.zeros(14), "std": np.ones(14), "min": -np.ones(14), "max": np.ones(14)},
        CAMERA: {k: np.full((3, 1, 1), v) for k, v in {"mean": 0.5, "std": 0.25, "min": 0.0, "max": 1.0}.items()},
    }
    pre, post = make_pre_post_processors(lr_cfg, dataset_stats=stats)
    at = next(i for i, s in enumerate(pre.steps) if isinstance(s, NormalizerProcessorStep))
    pre.steps.insert(at, ImageCropResizeProcessorStep(resize_size=tuple(cfg["image_size"])))
    return LeRobotPolicy(ACTPolicy(lr_cfg), pre, post, [CAMERA], name="act")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--queries", type=int, default=20, help="chunk queries per repeat and way")
    p.add_argument("--steps", type=int, default=150, help="control steps per episode")
    p.add_argument("--image", type=int, default=128, help="camera side in pixels (before the policy's resize)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    deterministic_torch(args.threads)
    policy = build_policy(args.image)
    rng = np.random.default_rng(0)
    obs = [{"observation.state": rng.normal(0, 0.1, 14).astype(np.float32),
            CAMERA: rng.integers(0, 255, (args.image, args.image, 3), dtype=np.uint8)} for _ in range(args.batch)]
    slots = list(range(args.batch))
    for s in slots:
        policy.reset(s, s)
    policy.predict_chunks(slots, obs)  # warm-up: first-call allocations

    best = {"single": float("inf"), "batched": float("inf")}
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for _ in range(args.queries):
            for s in slots:
                policy.predict_chunks([s], [obs[s]])
        best["single"] = min(best["single"], time.perf_counter() - t0)
        t0 = time.perf_counter()
        for _ in range(args.queries):
            chunks = policy.predict_chunks(slots, obs)
        best["batched"] = min(best["batched"], time.perf_counter() - t0)
    assert chunks.shape == (args.batch, 25, 14)
    queries_per_episode = args.steps / 5
    print(f"ACT {args.image}px -> {candidate_config('act', 'demo')['image_size']}, {args.threads} thread(s), "
          f"N={args.batch}, {args.queries} queries x {args.repeats} repeats (best)")
    rates = {}
    for way, seconds in best.items():
        qps = args.queries * args.batch / seconds
        rates[way] = qps / queries_per_episode
        print(f"  {way:>8}: {qps:8.1f} episode-queries/s = {rates[way]:6.2f} episodes/s of inference")
    print(f"  batched / single: {rates['batched'] / rates['single']:.2f}x")


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
