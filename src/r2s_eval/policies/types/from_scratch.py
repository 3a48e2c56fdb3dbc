"""Types trained from scratch on the lab's data (`act`, `diffusion`): a lerobot config class filled
from our keys and the candidate's `overrides`."""

from __future__ import annotations

import dataclasses

from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.types.registry import PolicyType

# Settings that keep every candidate offline and CPU-sized, whatever the overrides say last.
_ALWAYS = {"pretrained_backbone_weights": None, "push_to_hub": False}
# Lerobot config tuples arrive as lists from YAML/JSON.
_TUPLE_FIELDS = ("down_dims", "resize_shape", "crop_shape", "optimizer_betas")


class ScratchType(PolicyType):
    pipeline_keys = ("chunk_size", "horizon", "n_action_steps", "device", "input_features", "output_features")

    def config_class(self):
        """The lerobot config class (imported on use: lerobot is heavy)."""
        raise NotImplementedError

    def chunk_kwargs(self, cfg: dict, kwargs: dict) -> None:
        """Set the lerobot fields that make the model predict `cfg['chunk_size']` actions a call."""
        raise NotImplementedError

    def lerobot_config(self, cfg: dict):
        cls = self.config_class()
        field_names = {f.name for f in dataclasses.fields(cls) if f.init}
        overrides = dict(cfg["overrides"])
        unknown = sorted(set(overrides) - field_names)
        if unknown:
            raise PolicyConfigError(
                f"unknown override key(s) {unknown} for {cls.__name__} (policy type {cfg['type']!r})"
            )
        # Chunking is ours: the model must predict `chunk_size` actions per call.
        for key in self.pipeline_keys:
            if key in overrides:
                raise PolicyConfigError(
                    f"override {key!r} is set by the pipeline (top-level 'chunk_size', rollout.horizon, "
                    f"the dataset features or the policy's device); remove it"
                )
        if overrides.get("pretrained_backbone_weights") is not None:
            raise PolicyConfigError(
                "override 'pretrained_backbone_weights' must be None: candidates train from scratch, offline"
            )
        kwargs = {"optimizer_lr": cfg["lr"], **overrides, **_ALWAYS, "device": cfg["device"]}
        for key in _TUPLE_FIELDS:
            if key in kwargs and isinstance(kwargs[key], list):
                kwargs[key] = tuple(kwargs[key])
        self.chunk_kwargs(cfg, kwargs)
        try:
            return cls(**kwargs)
        except (TypeError, ValueError, NotImplementedError) as exc:
            raise PolicyConfigError(f"invalid {cls.__name__} settings {overrides}: {exc}") from exc
