"""Policies for the tests: two behind the rollout loop's policy interface (the scripted operator,
which succeeds, and a frozen policy, which fails), and randomly initialised LeRobot policies saved
as training folders (no data, no training): the CPU line-up's ACT architecture and a small DDPM
Diffusion Policy, for tests of the model call and the rollout loops."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from r2s_eval.twin.operator import make_operator

ACTION_DIM = 14


class OperatorPolicy:
    """The scripted operator behind the policy interface (a policy that knows the task): it
    succeeds. Its operator is made at the first action, on the environment as the episode left it."""

    def __init__(self, env):
        self.env, self.op = env, None

    def reset(self):
        self.op = None

    def act(self, obs):
        if self.op is None:
            self.op = make_operator(self.env.task.key, self.env, np.random.default_rng(0))
        return self.op.act(obs)


class FrozenPolicy:
    """Holds the first state it sees: it never moves, so it fails."""

    def __init__(self):
        self.action = None

    def reset(self):
        self.action = None

    def act(self, obs):
        if self.action is None:
            self.action = np.asarray(obs["observation.state"], dtype=float).copy()
        return self.action


# A small Diffusion Policy that still goes through every part of the model call: two
# observation steps (a history per episode) and DDPM (fresh noise at every denoising step).
DIFFUSION = {
    "type": "diffusion", "steps": 1, "batch_size": 2, "lr": 1e-4, "image_size": [32, 32], "chunk_size": 8,
    "overrides": {"n_obs_steps": 2, "vision_backbone": "resnet18", "use_group_norm": True,
                  "spatial_softmax_num_keypoints": 8, "down_dims": [16, 32], "diffusion_step_embed_dim": 16,
                  "kernel_size": 3, "n_groups": 4, "noise_scheduler_type": "DDPM", "num_train_timesteps": 20,
                  "num_inference_steps": 4, "prediction_type": "epsilon"},
}


def _stats(keys: list[str]) -> dict:
    vector = {"mean": np.zeros(ACTION_DIM), "std": np.full(ACTION_DIM, 0.1),
              "min": -np.ones(ACTION_DIM), "max": np.ones(ACTION_DIM)}
    image = {k: np.full((3, 1, 1), v) for k, v in {"mean": 0.5, "std": 0.25, "min": 0.0, "max": 1.0}.items()}
    return {"observation.state": vector, "action": vector, **{k: image for k in keys}}


def save_random_policy(folder: Path, cameras: list[str], image_hw: tuple[int, int], kind: str = "act",
                       seed: int = 0) -> Path:
    """`kind` "act": the CPU line-up's ACT (conf/policies/cpu.yaml) reading `cameras` of
    `image_hw` pixels; "diffusion": `DIFFUSION`. Saved as a training output folder."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.processor import ImageCropResizeProcessorStep, NormalizerProcessorStep

    from r2s_eval.config import candidate_config
    from r2s_eval.policies.trained_config import make_lerobot_config, validate_policy_cfg

    keys = [f"observation.images.{c}" for c in cameras]
    if kind == "act":
        cfg = candidate_config("act", "demo", image_keys=keys)
    else:
        cfg = validate_policy_cfg({**DIFFUSION, "name": "diffusion", "image_keys": keys})
    lr_cfg = make_lerobot_config(cfg)
    lr_cfg.input_features = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(ACTION_DIM,))}
    lr_cfg.input_features.update({k: PolicyFeature(type=FeatureType.VISUAL, shape=(3, *image_hw)) for k in keys})
    lr_cfg.output_features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))}
    if kind != "act":
        lr_cfg.resize_shape = tuple(cfg["image_size"])
    torch.manual_seed(seed)
    policy = get_policy_class(cfg["type"])(lr_cfg)
    pre, post = make_pre_post_processors(lr_cfg, dataset_stats=_stats(keys))
    if kind == "act":  # as training does: lerobot's resize step before normalisation
        at = next(i for i, s in enumerate(pre.steps) if isinstance(s, NormalizerProcessorStep))
        pre.steps.insert(at, ImageCropResizeProcessorStep(resize_size=tuple(cfg["image_size"])))
    ckpt = folder / "pretrained_model"
    for part in (policy, pre, post):
        part.save_pretrained(ckpt)
    (ckpt / "runner_config.json").write_text(json.dumps({"chunk_size": cfg["chunk_size"], "image_keys": keys,
                                                         "policy_type": cfg["type"]}))
    return folder
