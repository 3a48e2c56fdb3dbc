"""In-process LeRobot policies behind the `ChunkPolicy` interface.

Covers what r2s-eval trains (ACT, Diffusion Policy, the VLA families) and any local LeRobot
`pretrained_model` folder. One model call serves a whole batch of episode slots. lerobot's own
`select_action` queues are not used: the evaluation's `RecedingHorizon` owns re-planning.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from r2s_eval.policies.interface import STATE_KEY, TASK_KEY, ChunkPolicy, PolicyError, PolicySpec

CHECKPOINT_SUBDIR = "pretrained_model"
RUNNER_CONFIG = "runner_config.json"  # our settings next to lerobot's files (cameras used)


class LeRobotPolicy(ChunkPolicy):
    def __init__(self, policy, preprocessor, postprocessor, image_keys: Sequence[str],
                 device: str = "cpu", name: str = "policy", identity: dict | None = None):
        from lerobot.utils.constants import ACTION

        self.policy = policy.eval()
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor
        self.device = torch.device(device)
        self.name = name
        self.policy_type = policy.config.type
        self.n_obs_steps = int(getattr(policy.config, "n_obs_steps", 1) or 1)
        features = policy.config.input_features
        self.spec = PolicySpec(
            cameras=tuple(image_keys),
            action_dim=int(policy.config.output_features[ACTION].shape[0]),
            max_chunk=self._model_chunk_len(),
            uses_state=STATE_KEY in features,
            uses_task=self._uses_language(),
            state_dim=int(features[STATE_KEY].shape[0]) if STATE_KEY in features else None,
        )
        self._identity = identity or {}
        self._history: dict[int, deque] = {}
        self._generators: dict[int, torch.Generator] = {}

    def _model_chunk_len(self) -> int:
        cfg = self.policy.config
        if self.policy_type == "diffusion":
            return int(min(cfg.n_action_steps, cfg.horizon - cfg.n_obs_steps + 1))
        return int(getattr(cfg, "chunk_size", None) or getattr(cfg, "n_action_steps", 1))

    def _uses_language(self) -> bool:
        # Policies whose preprocessor tokenises an instruction consume the task text.
        return any("token" in type(step).__name__.lower() for step in getattr(self.preprocessor, "steps", []))

    def metadata(self) -> dict:
        return {**super().metadata(), "policy_type": self.policy_type, **self._identity}

    # -- per-slot state ------------------------------------------------------------------------
    def reset(self, slot: int, seed: int) -> None:
        self._history[slot] = deque(maxlen=self.n_obs_steps)
        self._generators[slot] = torch.Generator(device="cpu").manual_seed(int(seed))

    def observe(self, slot: int, obs: dict) -> None:
        if self.n_obs_steps > 1:  # Diffusion conditions on the last n_obs_steps observations
            history = self._history.setdefault(slot, deque(maxlen=self.n_obs_steps))
            history.append(self._preprocess([self.select(obs)]))

    # -- inference -----------------------------------------------------------------------------
    def _to_batch(self, observations: Sequence[dict]) -> dict:
        batch = {}
        if self.spec.uses_state:
            batch[STATE_KEY] = torch.from_numpy(np.stack([o[STATE_KEY] for o in observations]).astype(np.float32))
        for key in self.spec.cameras:
            # Same convention as the dataset: float32 in [0, 1], channel first.
            imgs = np.stack([o[key] for o in observations])
            batch[key] = torch.from_numpy(imgs).permute(0, 3, 1, 2).float().div_(255.0)
        if self.spec.uses_task:
            batch[TASK_KEY] = [o.get(TASK_KEY, "") for o in observations]
        return batch

    def _preprocess(self, observations: Sequence[dict]) -> dict:
        return self.preprocessor(self._to_batch(observations))

    @torch.no_grad()
    def predict_chunks(self, slots: Sequence[int], observations: Sequence[dict]) -> np.ndarray:
        if self.policy_type == "diffusion":
            actions = self._diffusion_chunks(slots, observations)
        else:
            actions = self.policy.predict_action_chunk(self._preprocess(observations))
        actions = self.postprocessor(actions)
        return actions.detach().cpu().numpy().astype(np.float32)

    def _diffusion_chunks(self, slots: Sequence[int], observations: Sequence[dict]) -> torch.Tensor:
        from lerobot.utils.constants import OBS_IMAGES, OBS_STATE

        histories = []
        for slot, obs in zip(slots, observations, strict=True):
            history = list(self._history.get(slot) or [self._preprocess([obs])])
            while len(history) < self.n_obs_steps:  # first step: repeat it, as lerobot does
                history.insert(0, history[0])
            histories.append(history)
        state = torch.cat([torch.stack([h[OBS_STATE] for h in hist], dim=1) for hist in histories])
        images = torch.cat([
            torch.stack([torch.stack([h[k] for k in self.spec.cameras], dim=-4) for h in hist], dim=1)
            for hist in histories
        ])
        cfg = self.policy.config
        noise, step_seeds = [], []
        for slot in slots:
            gen = self._generators.setdefault(slot, torch.Generator(device="cpu").manual_seed(0))
            noise.append(torch.randn((1, cfg.horizon, self.spec.action_dim), generator=gen))
            step_seeds.append(int(torch.randint(0, 2**31 - 1, (1,), generator=gen)))
        # DDPM draws extra noise per denoising step from the global RNG: seed it locally.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(step_seeds[0] if len(step_seeds) == 1 else hash(tuple(step_seeds)) % 2**31)
            return self.policy.diffusion.generate_actions(
                {OBS_STATE: state, OBS_IMAGES: images}, noise=torch.cat(noise).to(self.device)
            )


def resolve_checkpoint(checkpoint_dir: str | Path) -> Path:
    """Accept either a training `out_dir` or its `pretrained_model/` folder."""
    path = Path(checkpoint_dir)
    if (path / CHECKPOINT_SUBDIR / "config.json").is_file():
        path = path / CHECKPOINT_SUBDIR
    if not (path / "config.json").is_file():
        # Checked here: lerobot would treat a missing folder as a hub id and try to download it.
        raise PolicyError(f"no LeRobot policy at {checkpoint_dir} (no config.json; expected a pretrained_model folder)")
    return path


def load_lerobot_policy(checkpoint_dir: str | Path, device: str = "cpu", name: str | None = None) -> LeRobotPolicy:
    """A local LeRobot `pretrained_model` folder (ours or anyone's) as a `ChunkPolicy`."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.types import FeatureType
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    ckpt = resolve_checkpoint(checkpoint_dir)
    try:
        cfg = PreTrainedConfig.from_pretrained(ckpt)
    except Exception as exc:  # draccus raises many kinds; all mean "not a LeRobot policy config"
        raise PolicyError(f"{ckpt}/config.json is not a LeRobot policy config: {exc}") from exc
    cfg.device = device
    cfg.pretrained_path = ckpt
    policy = get_policy_class(cfg.type).from_pretrained(ckpt, config=cfg)
    preprocessor, postprocessor = make_pre_post_processors(
        cfg, pretrained_path=str(ckpt), preprocessor_overrides={"device_processor": {"device": device}},
    )
    runner_cfg = json.loads((ckpt / RUNNER_CONFIG).read_text()) if (ckpt / RUNNER_CONFIG).is_file() else {}
    image_keys = runner_cfg.get("image_keys") or [
        k for k, ft in cfg.input_features.items() if ft.type is FeatureType.VISUAL
    ]
    return LeRobotPolicy(policy, preprocessor, postprocessor, image_keys, device=device,
                         name=name or cfg.type, identity={"checkpoint": str(ckpt)})
