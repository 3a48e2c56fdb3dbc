"""In-process LeRobot policies behind the `ChunkPolicy` interface.

Covers what r2s-eval trains (ACT, Diffusion Policy, the VLA families) and any local LeRobot
`pretrained_model` folder. One model call serves a whole batch of episode slots. lerobot's own
`select_action` queues are not used: the evaluation's `RecedingHorizon` owns re-planning.

What a slot gets must not depend on which other slots share its call, or an episode's result
would depend on how many episodes run side by side:

- Rounding: a batched forward takes other kernel paths than a single one (at batch 1 torch runs
  ResNet's 3x3 convolutions through im2col + GEMM, at batch 2 and more through oneDNN; the
  transformer's GEMMs block by row count), so the same observation gives actions a few ulps
  apart at different batch sizes; even at one shape, a GEMM's last rows may take a tail kernel
  that rounds differently from the others. With `call_batch`, every model call has exactly that
  many rows and slot `s` always sits in row `s % call_batch` (callers number slots by episode, so
  an episode keeps its row whatever else runs): the other rows are padded with copies of a real
  observation, and slots that want the same row go in separate calls. At a fixed shape and row,
  what a row gets does not depend on the other rows (`tests/policies/test_policies_batch.py`
  checks it).
- Noise: sampling policies draw their noise per slot from the slot's generator (seeded by
  `reset`), never from one draw shared by the batch.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from r2s_eval.policies.checkpoint_files import RUNNER_CONFIG, WEIGHTS_FILE, checkpoint_hash, resolve_checkpoint
from r2s_eval.policies.interface import STATE_KEY, TASK_KEY, ChunkPolicy, PolicyError, PolicySpec
from r2s_eval.policies.types import loaded_type



class LeRobotPolicy(ChunkPolicy):
    def __init__(self, policy, preprocessor, postprocessor, image_keys: Sequence[str],
                 device: str = "cpu", name: str = "policy", identity: dict | None = None,
                 call_batch: int | None = None):
        """`call_batch`: rows of every model call (see the module docstring); None: each call
        has as many rows as slots asked, and its rounding depends on that number."""
        from lerobot.utils.constants import ACTION

        self.policy = policy.eval()
        # What the model's type does differently (its noise, its speed-ups): r2s_eval.policies.types.
        self.kind = loaded_type(policy.config.type)
        self.call_batch = None if call_batch is None else int(call_batch)
        if self.call_batch is not None and self.call_batch < 1:
            raise PolicyError(f"policy {name!r}: call_batch must be >= 1, got {call_batch}")
        if self.call_batch is not None:
            self.kind.prepare_for_batches(policy)
        if self.call_batch is not None and torch.device(device).type == "cpu":
            # Channels-last weights: oneDNN's convolutions then take them as they are instead of
            # reordering every weight at every call (half the time of a batched ResNet18 call).
            self.policy.to(memory_format=torch.channels_last)
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
            max_chunk=self.kind.model_chunk_len(policy.config),
            uses_state=STATE_KEY in features,
            uses_task=self._uses_language(),
            state_dim=int(features[STATE_KEY].shape[0]) if STATE_KEY in features else None,
        )
        self._identity = identity or {}
        self._history: dict[int, deque] = {}
        self._generators: dict[int, torch.Generator] = {}

    def _uses_language(self) -> bool:
        # Policies whose preprocessor tokenises an instruction consume the task text.
        return any("token" in type(step).__name__.lower() for step in getattr(self.preprocessor, "steps", []))

    def metadata(self) -> dict:
        if "checkpoint" in self._identity:  # by content (once), so a moved folder is the same policy
            self._identity["checkpoint_sha256"] = checkpoint_hash(self._identity.pop("checkpoint"))
        return {**super().metadata(), "policy_type": self.policy_type, **self._identity}

    # -- per-slot state ------------------------------------------------------------------------
    def reset(self, slot: int, seed: int) -> None:
        self._history[slot] = deque(maxlen=self.n_obs_steps)
        self._generators[slot] = torch.Generator(device="cpu").manual_seed(int(seed))

    def release(self, slot: int) -> None:
        self._history.pop(slot, None)
        self._generators.pop(slot, None)

    @property
    def observes_every_step(self) -> bool:
        return self.n_obs_steps > 1

    def observe(self, slot: int, obs: dict) -> None:
        if self.n_obs_steps > 1:  # Diffusion conditions on the last n_obs_steps observations
            history = self._history.setdefault(slot, deque(maxlen=self.n_obs_steps))
            history.append(self.preprocess([self.select(obs)]))

    def history(self, slot: int) -> deque | None:
        """The slot's last preprocessed observations (Diffusion's conditioning)."""
        return self._history.get(slot)

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

    def preprocess(self, observations: Sequence[dict]) -> dict:
        return self.preprocessor(self._to_batch(observations))

    @torch.no_grad()
    def predict_chunks(self, slots: Sequence[int], observations: Sequence[dict]) -> np.ndarray:
        if len(slots) != len(observations):
            raise PolicyError(f"policy {self.name!r}: {len(slots)} slots but {len(observations)} observations")
        if self.call_batch is None:
            return self._call(list(slots), list(observations))
        out: list[np.ndarray | None] = [None] * len(slots)
        pending = list(range(len(slots)))
        while pending:  # one call per round; slots whose row is taken wait for the next round
            rows: dict[int, int] = {}  # row of the call -> index into slots
            waiting = []
            for i in pending:
                row = int(slots[i]) % self.call_batch
                one_slot = self.kind.one_slot_per_call and rows  # the draw must be the slot's alone
                if row in rows or one_slot:
                    waiting.append(i)
                else:
                    rows[row] = i
            first = observations[next(iter(rows.values()))]
            call_slots: list[int | None] = [None] * self.call_batch  # None: a padding row
            call_obs = [first] * self.call_batch  # padding rows repeat a real observation
            for row, i in rows.items():
                call_slots[row], call_obs[row] = slots[i], observations[i]
            chunks = self._call(call_slots, call_obs)
            for row, i in rows.items():
                out[i] = chunks[row]
            pending = waiting
        return np.stack(out)

    def generator(self, slot: int | None) -> torch.Generator:
        if slot is None:  # a padding row: any fixed draw
            return torch.Generator(device="cpu").manual_seed(0)
        return self._generators.setdefault(slot, torch.Generator(device="cpu").manual_seed(0))

    def _call(self, slots: list[int | None], observations: list[dict]) -> np.ndarray:
        """One model call; row i belongs to `slots[i]`."""
        actions = self.kind.predict(self, slots, observations)
        actions = self.postprocessor(actions)
        return actions.detach().cpu().numpy().astype(np.float32)


def checkpoint_state_dict(policy, raw: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """`raw` (a model.safetensors) under the names `policy.state_dict()` uses, with the key fixes
    the family's own `from_pretrained` applies (openpi-era pi checkpoints, the vendored Florence-2
    layout of X-VLA, tied embeddings that safetensors stores once)."""
    return loaded_type(policy.config.type).checkpoint_state_dict(policy, raw)


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
    call_batch: int | None = None,
) -> LeRobotPolicy:
    """A local LeRobot `pretrained_model` folder (ours or anyone's) as a `ChunkPolicy`.

    `tokenizer_path`: local folder of the tokenizer / processor a VLA's preprocessor loads (saved
    pipelines name hub ids); default: the one recorded at training in `runner_config.json`.
    `call_batch`: rows of every model call (`LeRobotPolicy`).
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
    loaded_type(cfg.type).prepare_loaded_config(cfg, tokenizer)
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
                         name=name or cfg.type, identity={"checkpoint": str(ckpt)}, call_batch=call_batch)
