"""Diffusion Policy, trained from scratch; its noise is drawn per slot at every denoising step."""

from __future__ import annotations

from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.from_scratch import ScratchType


@register
class Diffusion(ScratchType):
    name = "diffusion"

    def config_class(self):
        from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

        return DiffusionConfig

    def chunk_kwargs(self, cfg: dict, kwargs: dict) -> None:
        # Diffusion predicts `horizon` steps starting n_obs_steps-1 in the past and its
        # generate_actions keeps `n_action_steps` of them: ask it for the whole chunk.
        n_obs = int(kwargs.get("n_obs_steps", 2))
        n_down = len(kwargs.get("down_dims", (512, 1024, 2048)))
        horizon = diffusion_horizon(cfg["chunk_size"], n_obs, n_down)
        kwargs.update(horizon=horizon, n_action_steps=cfg["chunk_size"])
        # lerobot's recipe: don't sample the last frames whose windows would be mostly padding.
        kwargs.setdefault("drop_n_last_frames", horizon - cfg["chunk_size"] - n_obs + 1)

    def set_training_inputs(self, cfg: dict, lr_cfg, features: dict) -> None:
        if cfg["image_size"] is not None:
            # Diffusion resizes inside its RGB encoder (handles the observation-history axis).
            lr_cfg.resize_shape = tuple(cfg["image_size"])

    def model_chunk_len(self, lr_cfg) -> int:
        return int(min(lr_cfg.n_action_steps, lr_cfg.horizon - lr_cfg.n_obs_steps + 1))

    def predict(self, runner, slots, observations):
        import torch
        from lerobot.utils.constants import OBS_IMAGES, OBS_STATE

        histories = {}
        for i, (slot, obs) in enumerate(zip(slots, observations, strict=True)):
            if slot is not None:
                history = list(runner.history(slot) or [runner.preprocess([obs])])
                while len(history) < runner.n_obs_steps:  # first step: repeat it, as lerobot does
                    history.insert(0, history[0])
                histories[i] = history
        pad = next(iter(histories.values()))  # padding rows repeat a real row's history
        histories = [histories.get(i, pad) for i in range(len(slots))]
        state = torch.cat([torch.stack([h[OBS_STATE] for h in hist], dim=1) for hist in histories])
        images = torch.cat([
            torch.stack([torch.stack([h[k] for k in runner.spec.cameras], dim=-4) for h in hist], dim=1)
            for hist in histories
        ])
        cfg = runner.policy.config
        generators = [runner.generator(s) for s in slots]
        noise = torch.cat([torch.randn((1, cfg.horizon, runner.spec.action_dim), generator=g) for g in generators])
        # lerobot's generate_actions, with the denoising steps' noise drawn per row from the
        # row's own generator (DDPM draws fresh noise at every step).
        model = runner.policy.diffusion
        global_cond = model._prepare_global_conditioning({OBS_STATE: state, OBS_IMAGES: images})
        actions = model.conditional_sample(len(slots), global_cond=global_cond, generator=generators,
                                           noise=noise.to(runner.device))
        start = runner.n_obs_steps - 1
        return actions[:, start : start + cfg.n_action_steps]


def diffusion_horizon(chunk_size: int, n_obs_steps: int, n_down: int) -> int:
    """Smallest horizon covering the chunk that the UNet can downsample (multiple of 2**n_down)."""
    need = chunk_size + n_obs_steps - 1
    factor = 2**n_down
    return -(-need // factor) * factor
