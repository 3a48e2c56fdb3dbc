"""Closed-loop inference with an explicit receding horizon.

Every `n_action_steps` actions the runner asks the model for a fresh chunk of `chunk_size`
actions and executes its first `n_action_steps`. lerobot's own `select_action` queues are not
used: the runner owns the observation history (Diffusion conditions on the last `n_obs_steps`
observations) and the action queue, so re-planning frequency is a setting of the evaluation,
not of the checkpoint.
"""

from __future__ import annotations

import json
import time
from collections import deque
from pathlib import Path

import numpy as np
import torch

from r2s_eval.policies.train import CHECKPOINT_SUBDIR, RUNNER_CONFIG


class PolicyRunner:
    """Wraps a lerobot policy and its processors; `act(obs)` returns one 14-D action."""

    def __init__(
        self,
        policy,
        preprocessor,
        postprocessor,
        image_keys: list[str],
        chunk_size: int = 25,
        n_action_steps: int = 5,
        seed: int = 0,
        device: str = "cpu",
    ):
        from lerobot.utils.constants import ACTION

        self.policy = policy.eval()
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor
        self.image_keys = list(image_keys)
        self.device = torch.device(device)
        self.policy_type = policy.config.type
        self.n_obs_steps = int(getattr(policy.config, "n_obs_steps", 1))
        self.action_dim = int(policy.config.output_features[ACTION].shape[0])
        max_chunk = self._model_chunk_len()
        if not 1 <= n_action_steps <= chunk_size <= max_chunk:
            raise ValueError(
                f"need 1 <= n_action_steps ({n_action_steps}) <= chunk_size ({chunk_size}) <= "
                f"the model's chunk length ({max_chunk})"
            )
        self.chunk_size = int(chunk_size)
        self.n_action_steps = int(n_action_steps)
        self.seed = int(seed)
        self.total_model_calls = 0
        self.total_inference_s = 0.0
        self.reset()

    def _model_chunk_len(self) -> int:
        cfg = self.policy.config
        if self.policy_type == "diffusion":
            return int(min(cfg.n_action_steps, cfg.horizon - cfg.n_obs_steps + 1))
        return int(getattr(cfg, "chunk_size", getattr(cfg, "n_action_steps", 1)))

    # -- episode state -------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Start a new episode: clear history and queue, re-seed the sampling noise."""
        if seed is not None:
            self.seed = int(seed)
        self._history: deque[dict[str, torch.Tensor]] = deque(maxlen=self.n_obs_steps)
        self._queue: deque[np.ndarray] = deque()
        self._generator = torch.Generator(device="cpu").manual_seed(self.seed)
        self.last_chunk: np.ndarray | None = None
        self.model_calls = 0
        self.inference_s = 0.0
        self.chunk_times_s: list[float] = []
        self.steps = 0

    @property
    def stats(self) -> dict:
        """Counters of the current episode (since `reset`)."""
        return {
            "steps": self.steps,
            "model_calls": self.model_calls,
            "inference_s": self.inference_s,
            "mean_chunk_s": self.inference_s / self.model_calls if self.model_calls else 0.0,
        }

    # -- stepping ------------------------------------------------------------------------------
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """One action (float32, shape (action_dim,)) for the current observation."""
        self._history.append(self._preprocess(obs))
        while len(self._history) < self.n_obs_steps:  # first step: repeat it, as lerobot does
            self._history.append(self._history[-1])
        if not self._queue:
            t0 = time.perf_counter()
            chunk = self._predict_chunk()
            dt = time.perf_counter() - t0
            self.model_calls += 1
            self.total_model_calls += 1
            self.inference_s += dt
            self.total_inference_s += dt
            self.chunk_times_s.append(dt)
            self.last_chunk = chunk
            self._queue.extend(chunk[: self.n_action_steps])
        self.steps += 1
        return self._queue.popleft().copy()

    def _preprocess(self, obs: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        from lerobot.utils.constants import OBS_STATE

        missing = [k for k in (OBS_STATE, *self.image_keys) if k not in obs]
        if missing:
            raise KeyError(f"observation lacks {missing}; the policy needs {[OBS_STATE, *self.image_keys]}")
        batch = {OBS_STATE: torch.as_tensor(np.asarray(obs[OBS_STATE], dtype=np.float32))}
        for key in self.image_keys:
            img = np.asarray(obs[key])
            if img.ndim != 3 or img.shape[-1] != 3 or img.dtype != np.uint8:
                raise ValueError(f"observation {key!r} must be uint8 HxWx3, got {img.dtype} {img.shape}")
            # Same convention as the dataset: float32 in [0, 1], channel first.
            batch[key] = torch.from_numpy(img).permute(2, 0, 1).float().div_(255.0)
        return self.preprocessor(batch)

    @torch.no_grad()
    def _predict_chunk(self) -> np.ndarray:
        from lerobot.utils.constants import OBS_IMAGES, OBS_STATE

        if self.policy_type == "diffusion":
            # Stack the history ourselves and call the model directly (bypasses the policy queues).
            batch = {OBS_STATE: torch.stack([h[OBS_STATE] for h in self._history], dim=1)}
            batch[OBS_IMAGES] = torch.stack(
                [torch.stack([h[k] for k in self.image_keys], dim=-4) for h in self._history], dim=1
            )
            cfg = self.policy.config
            noise = torch.randn((1, cfg.horizon, self.action_dim), generator=self._generator)
            # DDPM draws extra noise per denoising step from the global RNG: seed it locally.
            step_seed = int(torch.randint(0, 2**31 - 1, (1,), generator=self._generator))
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(step_seed)
                actions = self.policy.diffusion.generate_actions(batch, noise=noise.to(self.device))
        else:
            actions = self.policy.predict_action_chunk(self._history[-1])
        actions = actions[:, : self.chunk_size]
        actions = self.postprocessor(actions)
        chunk = actions[0].detach().cpu().numpy().astype(np.float32)
        if chunk.shape != (self.chunk_size, self.action_dim):
            raise RuntimeError(
                f"{self.policy_type} returned a chunk of shape {chunk.shape}, "
                f"expected {(self.chunk_size, self.action_dim)}"
            )
        return chunk


def resolve_checkpoint(checkpoint_dir: str | Path) -> Path:
    """Accept either a training `out_dir` or its `pretrained_model/` folder."""
    path = Path(checkpoint_dir)
    if (path / CHECKPOINT_SUBDIR / "config.json").is_file():
        path = path / CHECKPOINT_SUBDIR
    if not (path / "config.json").is_file():
        # Checked here: lerobot would treat a non-directory as a hub id and try to download it.
        raise FileNotFoundError(f"no policy checkpoint at {checkpoint_dir} (missing config.json)")
    return path


def load_policy(
    checkpoint_dir: str | Path,
    device: str = "cpu",
    chunk_size: int | None = None,
    n_action_steps: int | None = None,
    seed: int = 0,
) -> PolicyRunner:
    """Reload a checkpoint written by `train_policy` (lerobot `from_pretrained`) as a PolicyRunner.

    `chunk_size` / `n_action_steps` default to the values the policy was trained with.
    """
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    ckpt = resolve_checkpoint(checkpoint_dir)
    cfg = PreTrainedConfig.from_pretrained(ckpt)
    cfg.device = device
    policy = get_policy_class(cfg.type).from_pretrained(ckpt, config=cfg)
    preprocessor, postprocessor = make_pre_post_processors(
        cfg,
        pretrained_path=str(ckpt),
        preprocessor_overrides={"device_processor": {"device": device}},
    )
    runner_cfg = {}
    if (ckpt / RUNNER_CONFIG).is_file():
        runner_cfg = json.loads((ckpt / RUNNER_CONFIG).read_text())
    from lerobot.configs.types import FeatureType

    image_keys = runner_cfg.get("image_keys") or [
        k for k, ft in cfg.input_features.items() if ft.type is FeatureType.VISUAL
    ]
    return PolicyRunner(
        policy,
        preprocessor,
        postprocessor,
        image_keys=image_keys,
        chunk_size=chunk_size or runner_cfg.get("chunk_size", 25),
        n_action_steps=n_action_steps or runner_cfg.get("n_action_steps", 5),
        seed=seed,
        device=device,
    )
