"""Compact, deterministic training loop built from lerobot's pieces.

Mirrors `lerobot_train.py` (make_policy from dataset metadata, make_pre_post_processors with the
dataset stats, delta timestamps from the policy config, the policy's optimiser preset, gradient
clipping, EpisodeAwareSampler where the policy asks for it) without accelerate, hub or env eval.

The fine-tuned (VLA) types (`r2s_eval.policies.types`) fine-tune a pretrained checkpoint (`finetune.py`), with
an optional cosine schedule and an EMA of the weights (the checkpoint then holds the EMA weights).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from r2s_eval.data import open_metadata
from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.checkpoint_files import CHECKPOINT_SUBDIR, RUNNER_CONFIG, snapshot_folder
from r2s_eval.policies.finetune import EMA, build_vla_policy_and_processors
from r2s_eval.policies.trained_config import (
    cosine_floor_lr,
    make_lerobot_config,
    resolve_tokenizer_path,
    validate_policy_cfg,
)
from r2s_eval.policies.types import policy_type
from r2s_eval.policies.data import check_features, floor_spread, make_training_dataset, select_episodes
from r2s_eval.utils.io import atomic_dir, current_provenance
from r2s_eval.utils.numerics import deterministic_torch

log = logging.getLogger(__name__)

TRAIN_LOG = "train_log.json"


def policy_config(policy_cfg: dict, meta):
    """Our validated config and the lerobot config, with the inputs restricted to the listed cameras."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.utils.feature_utils import dataset_to_policy_features
    from lerobot.utils.constants import ACTION, OBS_STATE

    cfg = validate_policy_cfg(policy_cfg)
    check_features(meta, cfg["image_keys"])
    lr_cfg = make_lerobot_config(cfg)

    # Only the state and the listed cameras are policy inputs; make_policy keeps preset inputs.
    features = dataset_to_policy_features(meta.features)
    inputs = {OBS_STATE: features[OBS_STATE]}
    for key in cfg["image_keys"]:
        inputs[key] = PolicyFeature(type=FeatureType.VISUAL, shape=features[key].shape)
    lr_cfg.input_features = inputs
    lr_cfg.output_features = {ACTION: features[ACTION]}
    kind = policy_type(cfg["type"])
    kind.set_training_inputs(cfg, lr_cfg, features)
    if kind.fine_tunes:
        resolve_tokenizer_path(cfg, lr_cfg)  # fail now, before the data is decoded
    return cfg, lr_cfg


def build_policy_and_processors(policy_cfg: dict, meta, stats: dict | None = None):
    """lerobot config + policy + (pre, post) processors for `policy_cfg` on dataset `meta`.

    `stats` replaces the dataset's normalisation statistics (default: `meta.stats`).
    """
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    cfg, lr_cfg = policy_config(policy_cfg, meta)
    kind = policy_type(cfg["type"])
    if kind.fine_tunes:
        return build_vla_policy_and_processors(cfg, lr_cfg, meta, stats)[:5]
    policy = make_policy(lr_cfg, ds_meta=meta)
    preprocessor, postprocessor = make_pre_post_processors(lr_cfg, dataset_stats=stats or meta.stats)
    kind.adapt_preprocessor(cfg, preprocessor)
    return cfg, lr_cfg, policy, preprocessor, postprocessor


def _lr_lambda(cfg: dict):
    """Multiplier of the base learning rate per scheduler step (None: constant)."""
    warm, steps = int(cfg["warmup_steps"]), int(cfg["steps"])
    if cfg["scheduler"] == "constant":
        if warm <= 0:
            return None
        return lambda s: min(1.0, (s + 1) / warm)
    floor = cosine_floor_lr(cfg) / float(cfg["lr"])
    # Step n (1-based) runs at lambda(n - 1): the last step reaches the floor exactly.
    span = max(1, steps - warm - 1)

    def cosine(s: int) -> float:
        if s < warm:
            return (s + 1) / warm
        progress = min(1.0, (s - warm) / span)
        return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return cosine


def _make_optimizer(cfg: dict, lr_cfg, policy):
    preset = lr_cfg.get_optimizer_preset()
    preset.lr = cfg["lr"]
    if cfg["weight_decay"] is not None:
        preset.weight_decay = cfg["weight_decay"]
    if cfg["betas"] is not None:
        preset.betas = tuple(cfg["betas"])
    params = policy.get_optim_params()
    classes = {"adamw": torch.optim.AdamW, "adam": torch.optim.Adam}
    if preset.type in classes:
        # Same hyper-parameters as preset.build(), but the fused kernel: on CPU the optimiser
        # step over a ResNet18 costs ~5x less than the default for-each implementation.
        kwargs = dataclasses.asdict(preset)
        kwargs.pop("grad_clip_norm")
        optimizer = classes[preset.type](params, **kwargs, fused=True)
    else:
        optimizer = preset.build(params)
    scheduler = None
    lr_lambda = _lr_lambda(cfg)
    if lr_lambda is not None:
        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lr_lambda)
    return optimizer, scheduler


def _make_loader(dataset, lr_cfg, batch_size: int, seed: int):
    from lerobot.datasets.sampler import EpisodeAwareSampler

    generator = torch.Generator().manual_seed(seed)
    if hasattr(lr_cfg, "drop_n_last_frames"):
        sampler = EpisodeAwareSampler(
            dataset.meta.episodes["dataset_from_index"],
            dataset.meta.episodes["dataset_to_index"],
            episode_indices_to_use=dataset.episodes,
            drop_n_last_frames=lr_cfg.drop_n_last_frames,
            shuffle=True,  # draws from the global torch RNG, seeded by set_seed
        )
        return torch.utils.data.DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=0)
    return torch.utils.data.DataLoader(
        dataset, batch_size=batch_size, shuffle=True, generator=generator, num_workers=0
    )


def clip_gradients(policy, max_norm: float) -> torch.Tensor:
    """`torch.nn.utils.clip_grad_norm_`, with the gradients rescaled only when their norm is over
    `max_norm` (the stock function multiplies them by 1.0 otherwise: a pass over every gradient
    for nothing). Returns the norm before clipping."""
    grads = [p.grad for p in policy.parameters() if p.grad is not None]
    norm = torch.nn.utils.get_total_norm(grads)
    if max_norm / (float(norm) + 1e-6) < 1.0:  # the stock function's clip coefficient
        torch.nn.utils.clip_grads_with_norm_(policy.parameters(), max_norm, norm)
    return norm


def _cycle(loader):
    while True:
        yield from loader


def training_seed(seed: int, replicate: int) -> int:
    """The experiment's seed for the candidate itself (replicate 0); one drawn from both for
    each further replicate."""
    return seed if replicate == 0 else int(np.random.SeedSequence([seed, replicate]).generate_state(1)[0])


def require_device(device: str, name: str) -> None:
    """Refuse a `device` this machine lacks. lerobot falls back to the CPU on its own when CUDA is
    missing, so a training the config put on a GPU would run on the CPU and still be logged on
    the GPU."""
    where = f"policies.{name}.device"
    try:
        wanted = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise PolicyConfigError(f"{where}: {device!r} is not a torch device ('cpu', 'cuda', 'cuda:1', 'mps')") from e
    if wanted.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0 or (wanted.index or 0) >= count:
            raise PolicyConfigError(
                f"{where} is {device!r}, but this machine has {count} CUDA device(s): train it on a GPU "
                f"node, or set {where}=cpu"
            )
    if wanted.type == "mps" and not torch.backends.mps.is_available():
        raise PolicyConfigError(f"{where} is 'mps', but this machine has no Apple GPU: set {where}=cpu")


def train_policy(
    dataset_root: str | Path,
    repo_id: str,
    policy_cfg: dict,
    out_dir: str | Path,
    seed: int,
    episodes: list[int] | None = None,
    replicate: int = 0,
    snapshot_steps: Sequence[int] = (),
) -> dict[str, Any]:
    """Train one policy on one dataset; write `out_dir/pretrained_model/` and `out_dir/train_log.json`.

    `seed` is the experiment's, unless the policy states its own (`seed`); replicate k > 0 (the
    policy's `seeds`) trains the candidate again from a seed drawn from that and k (`training_seed`). Training runs on the policy's `device`.
    `episodes` restricts training to those episode indices (ingest's index: the episodes that
    passed its checks); None uses every episode of the dataset. `snapshot_steps`: steps after
    which the weights are saved as well (`snapshot_folder`), each below the last.

    The whole `out_dir` is written in a temporary sibling and renamed at the end, so an interrupted
    run never leaves a checkpoint that looks complete. Returns the summary stored in the log.
    """
    from lerobot.utils.random_utils import set_seed

    t_start, cpu_start = time.perf_counter(), time.process_time()
    cfg = validate_policy_cfg(policy_cfg)
    snapshot_steps = {int(s) for s in snapshot_steps}
    late = sorted(s for s in snapshot_steps if not 1 <= s < int(cfg["steps"]))
    if late:
        raise ValueError(f"snapshot steps {late} of {cfg['name'] or cfg['type']!r}: each must be in [1, "
                         f"{cfg['steps']}) (the last step's weights are the training's own)")
    if cfg["seed"] is not None:
        seed = int(cfg["seed"])
    seed, device = training_seed(seed, replicate), cfg["device"]
    require_device(device, cfg["name"] or cfg["type"])
    deterministic_torch(int(cfg["threads"]))
    set_seed(seed)

    meta = open_metadata(dataset_root, repo_id)
    _, lr_cfg = policy_config(cfg, meta)
    t_data = time.perf_counter()
    episodes = select_episodes(meta, float(cfg["episodes_fraction"]), episodes)
    dataset = make_training_dataset(dataset_root, repo_id, meta, lr_cfg, cfg["image_keys"], episodes)
    data_prep_s = time.perf_counter() - t_data
    # The metadata's per-channel image std can be near zero (lerobot 0.4.4 aggregates it that
    # way), which would scale pixels by ~1000 before the CNN and amplify sensor noise; normalise
    # with statistics measured on the frames actually trained on.
    stats = {**meta.stats, **dataset.image_stats()}
    vla = policy_type(cfg["type"]).fine_tunes
    if vla:
        stats = dataset.with_quantiles(stats)  # pi0.5 normalises with q01 / q99
    stats, floored = floor_spread(stats, float(cfg["std_floor"]), meta.features)
    for key, names in floored.items():
        log.info("%s: %d feature(s) barely move in the training data; normalised with the spread floor %g: %s",
                 key, len(names), cfg["std_floor"], names)
    set_seed(seed)  # initial weights depend on the seed alone, not on what loading the data drew
    load_report = None
    if vla:
        cfg, lr_cfg, policy, preprocessor, postprocessor, load_report = build_vla_policy_and_processors(
            cfg, lr_cfg, meta, stats
        )
    else:
        cfg, lr_cfg, policy, preprocessor, postprocessor = build_policy_and_processors(cfg, meta, stats)
    loader = _make_loader(dataset, lr_cfg, cfg["batch_size"], seed)
    optimizer, scheduler = _make_optimizer(cfg, lr_cfg, policy)
    clip = cfg["grad_clip_norm"]
    grad_clip = float(clip if clip is not None else lr_cfg.get_optimizer_preset().grad_clip_norm)
    ema = EMA(policy, cfg["ema_decay"]) if cfg["ema_decay"] is not None else None

    runner_cfg = {"chunk_size": cfg["chunk_size"], "image_keys": cfg["image_keys"], "policy_type": cfg["type"]}
    if vla:
        # Saved pipelines name the hub id; reloads read the tokenizer from this folder.
        runner_cfg.update(tokenizer_path=load_report["tokenizer_path"], pretrained_path=load_report["pretrained_path"],
                          weights="ema" if ema is not None else "last")

    def save_checkpoint(folder: Path) -> None:
        ckpt = folder / CHECKPOINT_SUBDIR
        policy.save_pretrained(ckpt)
        preprocessor.save_pretrained(ckpt)
        postprocessor.save_pretrained(ckpt)
        (ckpt / RUNNER_CONFIG).write_text(json.dumps(runner_cfg, indent=2) + "\n")

    losses: list[dict[str, float]] = []
    window: list[float] = []
    batches = _cycle(loader)
    out_dir = Path(out_dir)
    # Snapshots are written into the same temporary folder as the last weights: an interrupted
    # training leaves neither.
    with atomic_dir(out_dir) as tmp:
        policy.train()
        t_loop, cpu_loop = time.perf_counter(), time.process_time()
        with policy_type(cfg["type"]).training_speedups(policy):
            for step in range(1, int(cfg["steps"]) + 1):
                batch = preprocessor(next(batches))
                loss, _ = policy.forward(batch)
                if not torch.isfinite(loss):
                    raise FloatingPointError(
                        f"non-finite loss {loss.item()} at step {step} ({cfg['type']}, seed {seed}, data {repo_id})"
                    )
                loss.backward()
                grad_norm = clip_gradients(policy, grad_clip)
                optimizer.step()
                optimizer.zero_grad(set_to_none=True)
                if scheduler is not None:
                    scheduler.step()
                if ema is not None:
                    ema.update()
                window.append(loss.item())
                if step % cfg["log_every"] == 0 or step == cfg["steps"] or step == 1:
                    losses.append(
                        {
                            "step": step,
                            "loss": sum(window) / len(window),  # mean over the steps since the last entry
                            "grad_norm": float(grad_norm),
                            # X-VLA's first group is its VLM at lr / 10: log the base rate.
                            "lr": max(g["lr"] for g in optimizer.param_groups) if vla else optimizer.param_groups[0]["lr"],
                            "elapsed_s": time.perf_counter() - t_loop,
                        }
                    )
                    window = []
                if step in snapshot_steps:
                    # Saving reads the weights and draws no random number: the run goes on as without.
                    with ema.applied() if ema is not None else contextlib.nullcontext():
                        save_checkpoint(snapshot_folder(tmp, step))
        loop_s = time.perf_counter() - t_loop
        loop_cpu_s = time.process_time() - cpu_loop
        policy.eval()
        if ema is not None:
            ema.copy_to()
            log.info("the checkpoint holds the EMA weights (decay %s), not the last optimiser step's", cfg["ema_decay"])

        n_params = sum(p.numel() for p in policy.parameters())
        summary = {
            "policy_type": cfg["type"],
            "name": cfg["name"],
            "repo_id": repo_id,
            "dataset_root": str(dataset_root),
            "num_frames": dataset.num_frames,
            "num_episodes": dataset.num_episodes,
            "seed": seed,
            "device": device,
            "threads": int(cfg["threads"]),
            "steps": int(cfg["steps"]),
            "snapshot_steps": sorted(snapshot_steps),
            "batch_size": int(cfg["batch_size"]),
            "num_params": n_params,
            "first_loss": losses[0]["loss"] if losses else None,
            "final_loss": losses[-1]["loss"] if losses else None,
            "data_prep_s": data_prep_s,
            "train_loop_s": loop_s,
            "train_loop_cpu_s": loop_cpu_s,  # wall time is inflated on a shared machine; CPU time is not
            "s_per_step": loop_s / max(1, int(cfg["steps"])),
            "torch_version": torch.__version__,
            "python": platform.python_version(),
            "cpu_capability": torch.backends.cpu.get_cpu_capability(),  # kernels used (pinned on import)
            "std_floored": floored,  # features normalised with the spread floor (std_floor), per key
        }
        if vla:
            summary["weights"] = runner_cfg["weights"]
            summary["ema_decay"] = cfg["ema_decay"]
            summary["grad_clip_norm"] = grad_clip
            summary["pretrained"] = {
                "path": load_report["pretrained_path"],
                "tokenizer_path": load_report["tokenizer_path"],
                **load_report["counts"],
            }
        save_checkpoint(tmp)
        summary["wall_s"] = time.perf_counter() - t_start
        summary["cpu_s"] = time.process_time() - cpu_start
        train_log = {"summary": summary, "config": cfg, "losses": losses, "provenance": current_provenance()}
        if vla:
            train_log["pretrained_load"] = {k: load_report[k] for k in ("counts", "loaded", "resized", "new", "unused")}
        (tmp / TRAIN_LOG).write_text(json.dumps(train_log, indent=2, sort_keys=True) + "\n")
    log.info(
        "trained %s (%s) on %s: %d steps, loss %.4f -> %.4f, %.1fs",
        cfg["name"] or cfg["type"], cfg["type"], repo_id, cfg["steps"],
        summary["first_loss"], summary["final_loss"], summary["wall_s"],
    )
    return summary
