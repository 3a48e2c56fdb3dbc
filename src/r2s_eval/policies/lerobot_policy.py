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
WEIGHTS_FILE = "model.safetensors"
# Flow-matching VLAs draw their initial noise from torch's global RNG: seeded per episode slot.
_SAMPLING_TYPES = ("pi0", "pi05", "smolvla", "xvla")


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
        if "checkpoint" in self._identity:  # by content (once), so a moved folder is the same policy
            from r2s_eval.policies.sources import checkpoint_hash

            self._identity["checkpoint_sha256"] = checkpoint_hash(self._identity.pop("checkpoint"))
        return {**super().metadata(), "policy_type": self.policy_type, **self._identity}

    # -- per-slot state ------------------------------------------------------------------------
    def reset(self, slot: int, seed: int) -> None:
        self._history[slot] = deque(maxlen=self.n_obs_steps)
        self._generators[slot] = torch.Generator(device="cpu").manual_seed(int(seed))

    def release(self, slot: int) -> None:
        self._history.pop(slot, None)
        self._generators.pop(slot, None)

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
        elif self.policy_type in _SAMPLING_TYPES:
            batch = self._preprocess(observations)
            devices = [self.device] if self.device.type == "cuda" else []
            with torch.random.fork_rng(devices=devices):
                torch.manual_seed(self._call_seed(slots))
                actions = self.policy.predict_action_chunk(batch)
        else:
            actions = self.policy.predict_action_chunk(self._preprocess(observations))
        actions = self.postprocessor(actions)
        return actions.detach().cpu().numpy().astype(np.float32)

    def _call_seed(self, slots: Sequence[int]) -> int:
        seeds = []
        for slot in slots:
            gen = self._generators.setdefault(slot, torch.Generator(device="cpu").manual_seed(0))
            seeds.append(int(torch.randint(0, 2**31 - 1, (1,), generator=gen)))
        return seeds[0] if len(seeds) == 1 else hash(tuple(seeds)) % 2**31

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


def checkpoint_state_dict(policy, raw: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """`raw` (a model.safetensors) under the names `policy.state_dict()` uses, with the key fixes
    the family's own `from_pretrained` applies (openpi-era pi checkpoints, the vendored Florence-2
    layout of X-VLA, tied embeddings that safetensors stores once)."""
    policy_type = policy.config.type
    if policy_type in ("pi0", "pi05"):
        fixed = policy._fix_pytorch_state_dict_keys(raw, policy.config)
        return {k if k.startswith("model.") else f"model.{k}": v for k, v in fixed.items()}
    if policy_type == "xvla":
        from lerobot.policies.xvla import modeling_xvla

        if modeling_xvla._is_vendored_florence_state_dict(raw):
            raw = modeling_xvla._remap_vendored_florence_state_dict(raw)
        raw = dict(raw)
        shared, embed = "model.vlm.language_model.shared.weight", "model.vlm.language_model.encoder.embed_tokens.weight"
        if shared in raw and embed not in raw:
            raw[embed] = raw[shared]
        elif embed in raw and shared not in raw:
            raw[shared] = raw[embed]
    return dict(raw)


def weight_mismatches(policy, weights_file: str | Path, n_values: int = 16) -> list[str]:
    """How `policy`'s weights differ from `weights_file`: names missing on either side, shapes, and
    the values of `n_values` tensors spread over the model (a model left at its random
    initialisation differs everywhere, so a sample catches it without a second full copy)."""
    from safetensors.torch import load_file

    expected = checkpoint_state_dict(policy, load_file(str(weights_file)))
    actual = policy.state_dict()
    # A tensor tied to one that is in the file (stored once by safetensors) counts as loaded.
    present = {actual[k].data_ptr() for k in actual if k in expected}
    problems = [f"not in the file: {k}" for k in sorted(actual.keys() - expected.keys())
                if actual[k].data_ptr() not in present]
    problems += [f"not in the model: {k}" for k in sorted(expected.keys() - actual.keys())]
    common = sorted(expected.keys() & actual.keys())
    problems += [f"shape of {k}: file {tuple(expected[k].shape)}, model {tuple(actual[k].shape)}"
                 for k in common if expected[k].shape != actual[k].shape]
    same_shape = [k for k in common if expected[k].shape == actual[k].shape]
    step = max(1, len(same_shape) // max(1, n_values))
    for key in same_shape[::step]:
        if not torch.equal(expected[key].to(actual[key].dtype), actual[key].detach().cpu()):
            problems.append(f"values of {key}")
    return problems


def _has_tokenizer_step(ckpt: Path) -> bool:
    from lerobot.utils.constants import POLICY_PREPROCESSOR_DEFAULT_NAME

    path = ckpt / f"{POLICY_PREPROCESSOR_DEFAULT_NAME}.json"
    if not path.is_file():
        return False
    steps = json.loads(path.read_text()).get("steps", [])
    return any(step.get("registry_name") == "tokenizer_processor" for step in steps)


def load_lerobot_policy(
    checkpoint_dir: str | Path,
    device: str = "cpu",
    name: str | None = None,
    tokenizer_path: str | Path | None = None,
) -> LeRobotPolicy:
    """A local LeRobot `pretrained_model` folder (ours or anyone's) as a `ChunkPolicy`.

    `tokenizer_path`: local folder of the tokenizer / processor a VLA's preprocessor loads (saved
    pipelines name hub ids); default: the one recorded at training in `runner_config.json`.
    """
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.types import FeatureType
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    ckpt = resolve_checkpoint(checkpoint_dir)
    try:
        cfg = PreTrainedConfig.from_pretrained(ckpt)
    except Exception as exc:  # draccus raises many kinds; all mean "not a LeRobot policy config"
        raise PolicyError(f"{ckpt}/config.json is not a LeRobot policy config: {exc}") from exc
    if not (ckpt / WEIGHTS_FILE).is_file():
        raise PolicyError(f"no {WEIGHTS_FILE} in {ckpt}")
    runner_cfg = json.loads((ckpt / RUNNER_CONFIG).read_text()) if (ckpt / RUNNER_CONFIG).is_file() else {}
    tokenizer = tokenizer_path or runner_cfg.get("tokenizer_path")
    if tokenizer is not None and not Path(tokenizer).is_dir():
        raise PolicyError(f"{ckpt}: the tokenizer folder {str(tokenizer)!r} it needs does not exist")
    cfg.device = device
    cfg.pretrained_path = ckpt
    if cfg.type == "smolvla":
        cfg.load_vlm_weights = False  # every weight is in the checkpoint
        if tokenizer is not None:
            cfg.vlm_model_name = str(tokenizer)  # the VLM is built from that folder's config
    try:
        policy = get_policy_class(cfg.type).from_pretrained(ckpt, config=cfg)
    except Exception as exc:
        raise PolicyError(f"{ckpt}: could not build the {cfg.type} policy and load its weights: {exc}") from exc
    # Some from_pretrained (pi0, pi05) print load errors and return random weights, and the base
    # class loads non-strictly: check what arrived.
    problems = weight_mismatches(policy, ckpt / WEIGHTS_FILE)
    if problems:
        raise PolicyError(
            f"{ckpt}: the weights in {WEIGHTS_FILE} did not load into the {cfg.type} policy "
            f"({len(problems)} problems, e.g. {problems[:3]})"
        )
    overrides = {"device_processor": {"device": device}}
    if tokenizer is not None and _has_tokenizer_step(ckpt):
        overrides["tokenizer_processor"] = {"tokenizer_name": str(tokenizer)}
    preprocessor, postprocessor = make_pre_post_processors(
        cfg, pretrained_path=str(ckpt), preprocessor_overrides=overrides,
    )
    image_keys = runner_cfg.get("image_keys") or [
        k for k, ft in cfg.input_features.items() if ft.type is FeatureType.VISUAL
    ]
    return LeRobotPolicy(policy, preprocessor, postprocessor, image_keys, device=device,
                         name=name or cfg.type, identity={"checkpoint": str(ckpt)})
