"""Fine-tune pi0, pi0.5, SmolVLA and X-VLA from a pretrained folder with our training loop, reload,
and roll one episode out in the simulator; all offline.

The "pretrained" checkpoints are tiny, randomly initialised models of each family (see `tiny_vla`),
built with narrower state / action padding (8) than the robot's 14 dimensions, so the partial
loading has projections to resize. Their saved configs name the stock hub ids (as the LeRobot
base checkpoints do); training and reloading read the tokenizers / processors from local folders.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from r2s_eval.horizon import Horizon
from r2s_eval.policies import PolicyConfigError, PolicyError, load_policy, train_policy, validate_policy_cfg

from tests.helpers import datasets as synthetic
from tests.helpers import tiny_vla as tv

pytestmark = pytest.mark.timeout(600)

REPO_ID = "test/synthetic_bimanual"
CAMS = ("observation.images.head_left", "observation.images.wrist_left")
ROBOT_DIM = 14
PRETRAINED_DIM = 6  # the tiny checkpoints' own robot
PRETRAINED_PAD = 8  # their state / action padding, narrower than ROBOT_DIM
FAMILIES = ("pi0", "pi05", "smolvla", "xvla")
# Tensors that depend on the padded state / action width, per family.
RESIZED = {
    "pi0": {"model.state_proj.weight", "model.action_in_proj.weight", "model.action_out_proj.weight",
            "model.action_out_proj.bias"},
    "pi05": {"model.action_in_proj.weight", "model.action_out_proj.weight", "model.action_out_proj.bias"},
    "smolvla": {"model.state_proj.weight", "model.action_in_proj.weight", "model.action_out_proj.weight",
                "model.action_out_proj.bias"},
    "xvla": {"model.transformer.action_encoder.fc.weight", "model.transformer.action_decoder.fc.weight",
             "model.transformer.action_decoder.bias.weight"},
}


@pytest.fixture(scope="module")
def offline(tmp_path_factory):
    """Network refused, hub offline with a private cache holding only the tiny PaliGemma tokenizer,
    pi0 / pi0.5 built tiny."""
    with tv.tiny_pi_env(tmp_path_factory.mktemp("vla_hf") / "hub") as env:
        yield env
        assert env.network_attempts == []


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("vla_data") / "synthetic"
    return synthetic.build_dataset(root, REPO_ID, n_episodes=2, n_steps=16, image_hw=(64, 64), cameras=CAMS)


@pytest.fixture(scope="module")
def dataset_without_quantiles(dataset_root, tmp_path_factory) -> Path:
    """The same dataset with lerobot's quantile statistics removed from its metadata."""
    root = tmp_path_factory.mktemp("vla_data_noq") / "synthetic"
    shutil.copytree(dataset_root, root)
    stats_file = root / "meta" / "stats.json"
    stats = json.loads(stats_file.read_text())
    stats = {key: {k: v for k, v in s.items() if not k.startswith("q")} for key, s in stats.items()}
    stats_file.write_text(json.dumps(stats))
    return root


@pytest.fixture(scope="module")
def pretrained(offline, tmp_path_factory) -> dict[str, tuple[Path, str | None]]:
    """Per family: (pretrained checkpoint folder, tokenizer_path for the policy config)."""
    base = tmp_path_factory.mktemp("vla_pretrained")
    dims = {"state_dim": PRETRAINED_DIM, "action_dim": PRETRAINED_DIM, "cameras": CAMS,
            "max_state_dim": PRETRAINED_PAD, "max_action_dim": PRETRAINED_PAD}
    paligemma = offline.hub_cache / "models--google--paligemma-3b-pt-224" / "snapshots" / tv._SNAPSHOT
    smolvlm = tv.build_tiny_smolvlm(base / "smolvlm")
    bart = tv.build_xvla_tokenizer(base / "bart")
    return {
        # pi0 names its tokenizer folder; pi0.5 finds the hub id in the (private) local cache.
        "pi0": (tv.build_tiny_pi("pi0", base / "pi0", **dims), str(paligemma)),
        "pi05": (tv.build_tiny_pi("pi05", base / "pi05", **dims), None),
        "smolvla": (tv.build_tiny_smolvla(base / "smolvla", smolvlm, **dims), str(smolvlm)),
        "xvla": (tv.build_tiny_xvla(base / "xvla", bart, **dims), str(bart)),
    }


def _cfg(policy_type: str, pretrained: dict, **changes) -> dict:
    """The VLA recipe (defaults of the VLA types) at test size."""
    folder, tokenizer = pretrained[policy_type]
    cfg = {
        "type": policy_type,
        "name": policy_type,
        "pretrained_path": str(folder),
        "tokenizer_path": tokenizer,
        "steps": 3,
        "warmup_steps": 1,
        "batch_size": 4,
        "log_every": 1,
        "image_keys": list(CAMS),
        "image_size": [64, 64],
        "chunk_size": 10,
    }
    cfg.update(changes)
    return cfg


@pytest.fixture(scope="module")
def trained(offline, pretrained, dataset_root, dataset_without_quantiles, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("vla_trained")
    runs = {}
    for policy_type in FAMILIES:
        # pi0.5 normalises with q01 / q99: its data lacks them in the metadata.
        data = dataset_without_quantiles if policy_type == "pi05" else dataset_root
        train_policy(data, REPO_ID, _cfg(policy_type, pretrained), out / policy_type, seed=0)
        runs[policy_type] = out / policy_type
    return runs


def _log(run: Path) -> dict:
    return json.loads((run / "train_log.json").read_text())


# -- training ---------------------------------------------------------------------------------


@pytest.mark.parametrize("policy_type", FAMILIES)
def test_vla_fine_tunes_with_partial_loading(policy_type, trained, offline):
    run = trained[policy_type]
    log = _log(run)
    summary, load = log["summary"], log["pretrained_load"]
    assert summary["policy_type"] == policy_type and summary["steps"] == 3
    assert all(np.isfinite(e["loss"]) for e in log["losses"])
    # Partial loading: everything else came from the checkpoint, the padded projections grew 8 -> 14.
    resized = {entry["name"]: entry for entry in load["resized"]}
    assert set(resized) == RESIZED[policy_type]
    for entry in resized.values():
        assert entry["from"] != entry["to"] and len(entry["from"]) == len(entry["to"])
    assert load["new"] == [] and load["unused"] == []
    assert load["counts"] == {"loaded": len(load["loaded"]), "resized": len(resized), "new": 0, "unused": 0}
    assert len(load["loaded"]) > 20
    assert summary["pretrained"]["resized"] == len(resized) and summary["pretrained"]["loaded"] == len(load["loaded"])
    # The recipe: cosine from 2.5e-5 to 2.5e-6 (the last step runs at the floor), EMA weights saved.
    assert [e["lr"] for e in log["losses"]] == pytest.approx([2.5e-5, 2.5e-6, 2.5e-6])
    assert summary["weights"] == "ema" and summary["ema_decay"] == 0.9999
    assert log["config"]["betas"] == [0.9, 0.95] and log["config"]["scheduler"] == "cosine"

    ckpt = run / "pretrained_model"
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == policy_type and config["chunk_size"] == 10
    assert config["max_action_dim"] == ROBOT_DIM and config["max_state_dim"] == ROBOT_DIM
    assert config["output_features"]["action"]["shape"] == [ROBOT_DIM]
    assert tuple(config["optimizer_betas"]) == (0.9, 0.95)
    assert config["freeze_vision_encoder"] is False  # full fine-tuning
    # Saved files name hub ids, like the base checkpoints; runner_config.json the local folder.
    hub = {"pi0": tv.PALIGEMMA_TOKENIZER, "pi05": tv.PALIGEMMA_TOKENIZER,
           "smolvla": tv.SMOLVLM_HUB_NAME, "xvla": tv.XVLA_TOKENIZER_HUB_NAME}[policy_type]
    steps = json.loads((ckpt / "policy_preprocessor.json").read_text())["steps"]
    tokenizer_step = next(s for s in steps if s.get("registry_name") == "tokenizer_processor")
    assert tokenizer_step["config"]["tokenizer_name"] == hub
    runner_cfg = json.loads((ckpt / "runner_config.json").read_text())
    assert Path(runner_cfg["tokenizer_path"]).is_dir() and runner_cfg["weights"] == "ema"
    assert runner_cfg["image_keys"] == list(CAMS)
    if policy_type == "smolvla":
        assert config["vlm_model_name"] == hub and config["load_vlm_weights"] is False
        assert config["train_expert_only"] is False
    if policy_type == "xvla":
        assert config["tokenizer_name"] == hub and config["action_mode"] == "auto"
    assert offline.network_attempts == []


def test_pi05_quantile_stats_measured_when_missing(trained, dataset_without_quantiles):
    import pandas as pd
    from safetensors.torch import load_file

    from r2s_eval.data import open_metadata

    assert "q01" not in open_metadata(dataset_without_quantiles, REPO_ID).stats["action"]
    ckpt = trained["pi05"] / "pretrained_model"
    stats = load_file(next(ckpt.glob("policy_postprocessor*unnormalizer*.safetensors")))
    frames = pd.concat(pd.read_parquet(p) for p in sorted((dataset_without_quantiles / "data").rglob("*.parquet")))
    actions = np.stack(frames["action"].to_numpy()).astype(np.float64)
    for name, q in (("q01", 0.01), ("q99", 0.99)):
        expected = np.quantile(actions, q, axis=0)
        np.testing.assert_allclose(stats[f"action.{name}"].numpy(), expected, rtol=1e-5, atol=1e-6)


def test_partial_loading_copies_the_pretrained_slices(offline, pretrained, dataset_root):
    """The overlap of a resized tensor is the pretrained one, in the right place (X-VLA's flat
    domain-conditioned weights included); everything else is copied exactly."""
    from safetensors.torch import load_file

    from r2s_eval.data import open_metadata
    from r2s_eval.policies.lerobot_policy import checkpoint_state_dict
    from r2s_eval.policies.finetune import build_vla_policy_and_processors
    from r2s_eval.policies.train import policy_config

    meta = open_metadata(dataset_root, REPO_ID)
    for policy_type in ("pi0", "xvla"):
        cfg, lr_cfg = policy_config(_cfg(policy_type, pretrained), meta)
        _, _, policy, _, _, report = build_vla_policy_and_processors(cfg, lr_cfg, meta)
        source = checkpoint_state_dict(policy, load_file(str(pretrained[policy_type][0] / "model.safetensors")))
        state = policy.state_dict()
        for key in report["loaded"]:
            assert torch.equal(state[key], source[key]), key
        p = PRETRAINED_PAD
        if policy_type == "pi0":
            assert torch.equal(state["model.action_in_proj.weight"][:, :p], source["model.action_in_proj.weight"])
            assert torch.equal(state["model.action_out_proj.weight"][:p], source["model.action_out_proj.weight"])
            assert torch.equal(state["model.state_proj.weight"][:, :p], source["model.state_proj.weight"])
        else:
            hidden, t = policy.config.hidden_size, policy.config.dim_time
            key = "model.transformer.action_encoder.fc.weight"
            new = state[key].view(-1, 2 * ROBOT_DIM + t, hidden)
            old = source[key].view(-1, 2 * p + t, hidden)
            assert torch.equal(new[:, :p], old[:, :p])  # action inputs
            assert torch.equal(new[:, ROBOT_DIM : ROBOT_DIM + p], old[:, p : 2 * p])  # proprio inputs
            assert torch.equal(new[:, 2 * ROBOT_DIM :], old[:, 2 * p :])  # time inputs
            key = "model.transformer.action_decoder.fc.weight"
            assert torch.equal(state[key].view(-1, hidden, ROBOT_DIM)[:, :, :p], source[key].view(-1, hidden, p))


# -- reload and roll out ----------------------------------------------------------------------


@pytest.mark.parametrize("policy_type", FAMILIES)
def test_vla_reloads_and_rolls_out_in_sim(policy_type, trained, offline):
    from r2s_eval.rollout import run_episode
    from r2s_eval.sim.build import make_env
    from tests.helpers.worlds import bundled_world

    runner = load_policy(trained[policy_type], horizon=Horizon(10, 5))
    spec = runner.policy.spec
    assert spec.cameras == CAMS and spec.action_dim == ROBOT_DIM and spec.uses_task
    assert runner.horizon == Horizon(10, 5)
    world = {**bundled_world(), "image_height": 64, "image_width": 64, "cameras": [c.rsplit(".", 1)[1] for c in CAMS]}
    env = make_env("cup_on_plate", world)
    try:
        runner.reset(seed=3)
        poses = env.sample_initial_poses(np.random.default_rng(0))
        result = run_episode(env, runner, poses, seed=3, max_steps=10, video_camera="head_left")
    finally:
        env.close()
    traj = result.trajectory
    assert result.length == len(traj) == 10 and len(result.frames) == 11
    actions = np.stack(traj["action"].to_numpy())
    assert actions.shape == (10, ROBOT_DIM) and np.isfinite(actions).all()
    assert runner.model_calls == 2
    assert offline.network_attempts == []


def test_vla_sampling_is_seeded_per_episode(trained, offline):
    runner = load_policy(trained["pi0"], horizon=Horizon(10, 5))
    rng = np.random.default_rng(0)
    obs = {"observation.state": rng.normal(0, 0.1, ROBOT_DIM).astype(np.float32), "task": "pick the cube"}
    for cam in CAMS:
        obs[cam] = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)

    def first_chunk(seed):
        runner.reset(seed=seed)
        runner.act(obs)
        return runner.last_chunk.copy()

    a = first_chunk(5)
    np.testing.assert_array_equal(a, first_chunk(5))
    assert not np.array_equal(a, first_chunk(6))


@pytest.mark.parametrize("policy_type", FAMILIES)
def test_vla_chunks_do_not_depend_on_the_slots_beside_it(policy_type, trained, offline):
    """With a fixed call shape, a slot's sampled chunk is the same alone or beside another slot
    (its noise is its own: per-slot noise, or one slot per call for X-VLA)."""
    from r2s_eval.policies.lerobot_policy import load_lerobot_policy

    alone, together = _chunks_alone_and_together(load_lerobot_policy(trained[policy_type], call_batch=2))
    np.testing.assert_array_equal(alone[0], together[0])
    assert not np.array_equal(together[0], together[1])


def _chunks_alone_and_together(policy):
    """Slot 0's chunk predicted alone, then slots 0 and 3 predicted in one call."""
    rng = np.random.default_rng(1)
    obs = []
    for _ in range(2):
        o = {"observation.state": rng.normal(0, 0.1, ROBOT_DIM).astype(np.float32), "task": "pick the cube"}
        o.update({cam: rng.integers(0, 255, (64, 64, 3), dtype=np.uint8) for cam in CAMS})
        obs.append(policy.select(o))
    policy.reset(0, 5)
    alone = policy.predict_chunks([0], obs[:1])
    policy.reset(0, 5)
    policy.reset(3, 9)
    return alone, policy.predict_chunks([0, 3], obs)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU")
@pytest.mark.parametrize("policy_type", FAMILIES)
def test_vla_trains_and_predicts_on_cuda(policy_type, offline, pretrained, dataset_root, dataset_without_quantiles,
                                         tmp_path):
    """On a GPU box the recipe's `device: cuda` trains there and the reloaded policy predicts
    there, its chunks as on the CPU: finite, a slot's the same alone or beside another."""
    from r2s_eval.policies.lerobot_policy import load_lerobot_policy

    data = dataset_without_quantiles if policy_type == "pi05" else dataset_root
    allocations = torch.cuda.memory_stats().get("allocation.all.allocated", 0)
    train_policy(data, REPO_ID, _cfg(policy_type, pretrained, device="cuda"), tmp_path / policy_type, seed=0)
    # lerobot falls back to the CPU quietly; the training must have allocated on the GPU
    assert torch.cuda.memory_stats()["allocation.all.allocated"] > allocations
    assert np.isfinite([e["loss"] for e in _log(tmp_path / policy_type)["losses"]]).all()
    policy = load_lerobot_policy(tmp_path / policy_type, device="cuda", call_batch=2)
    assert next(policy.policy.parameters()).device.type == "cuda"
    alone, together = _chunks_alone_and_together(policy)
    assert np.isfinite(together).all() and together.shape[:2] == (2, 10)
    np.testing.assert_array_equal(alone[0], together[0])


def test_reload_refuses_weights_that_did_not_load(trained, offline, tmp_path):
    """pi0's from_pretrained prints load errors and returns random weights: the loader checks."""
    from safetensors.torch import load_file, save_file

    run = tmp_path / "pi0"
    shutil.copytree(trained["pi0"], run)
    weights_file = run / "pretrained_model" / "model.safetensors"
    weights = load_file(weights_file)
    key = "model.action_out_proj.weight"
    weights[key] = torch.zeros(weights[key].shape[0] + 1, weights[key].shape[1])
    save_file(weights, weights_file, metadata={"format": "pt"})
    with pytest.raises(PolicyError, match=r"pretrained_model.*did not load.*action_out_proj"):
        load_policy(run, horizon=Horizon(10, 5))

    runner_file = run / "pretrained_model" / "runner_config.json"
    runner_cfg = json.loads(runner_file.read_text())
    runner_cfg["tokenizer_path"] = str(tmp_path / "moved_away")
    runner_file.write_text(json.dumps(runner_cfg))
    with pytest.raises(PolicyError, match="moved_away"):
        load_policy(run, horizon=Horizon(10, 5))


# -- configuration errors ---------------------------------------------------------------------


def test_vla_recipe_defaults():
    cfg = validate_policy_cfg({"type": "pi05", "pretrained_path": "checkpoints/pi05_base"})
    assert (cfg["lr"], cfg["decay_lr"], cfg["scheduler"], cfg["warmup_steps"]) == (2.5e-5, 2.5e-6, "cosine", 2000)
    assert (cfg["betas"], cfg["ema_decay"], cfg["batch_size"], cfg["chunk_size"]) == ([0.9, 0.95], 0.9999, 32, 25)
    assert cfg["image_size"] == [224, 224] and len(cfg["image_keys"]) == 4
    act = validate_policy_cfg({"type": "act"})
    assert (act["scheduler"], act["ema_decay"], act["betas"], act["pretrained_path"]) == ("constant", None, None, None)


def test_vla_config_errors_name_the_setting(offline, pretrained, dataset_root, tmp_path):
    with pytest.raises(PolicyConfigError, match="pretrained_path"):
        validate_policy_cfg({"type": "smolvla"})
    with pytest.raises(PolicyConfigError, match="pretrained_path.*trains from scratch"):
        validate_policy_cfg({"type": "act", "pretrained_path": "x"})
    for policy_type in ("pi0_fast", "groot"):
        with pytest.raises(PolicyConfigError, match=f"{policy_type}.*not supported yet"):
            validate_policy_cfg({"type": policy_type, "pretrained_path": "x"})
    with pytest.raises(PolicyConfigError, match="tokenizer_pth"):
        validate_policy_cfg({**_cfg("pi0", pretrained), "tokenizer_pth": "x"})
    with pytest.raises(PolicyConfigError, match="scheduler"):
        validate_policy_cfg({**_cfg("pi0", pretrained), "scheduler": "linear"})

    def fails_at_start(cfg, pattern):
        out = tmp_path / cfg["name"]
        with pytest.raises(PolicyConfigError, match=pattern):
            train_policy(dataset_root, REPO_ID, cfg, out, seed=0)
        assert not out.exists()

    missing = tmp_path / "checkpoints" / "pi0_base"
    fails_at_start(_cfg("pi0", pretrained, pretrained_path=str(missing)),
                   rf"policies\.pi0\.pretrained_path.*{missing}.*does not exist")
    # No tokenizer folder and the hub id is not in the (private, offline) cache.
    fails_at_start(_cfg("smolvla", pretrained, tokenizer_path=None),
                   rf"policies\.smolvla\.tokenizer_path is not set.*{tv.SMOLVLM_HUB_NAME}")
    fails_at_start(_cfg("xvla", pretrained, tokenizer_path=str(tmp_path / "no_tok")),
                   r"policies\.xvla\.tokenizer_path.*no_tok.*does not exist")
    fails_at_start(_cfg("pi0", pretrained, name="mislabelled", pretrained_path=str(pretrained["smolvla"][0])),
                   r"policies\.mislabelled\.pretrained_path.*'smolvla' policy")
    fails_at_start(_cfg("xvla", pretrained, overrides={"depht": 2}), "depht")
    fails_at_start(_cfg("pi0", pretrained, overrides={"chunk_size": 4}), "chunk_size")
    assert offline.network_attempts == []


def test_cosine_schedule_and_ema_updates():
    from r2s_eval.policies.finetune import EMA
    from r2s_eval.policies.train import _lr_lambda

    cfg = validate_policy_cfg({"type": "pi0", "pretrained_path": "x", "steps": 12, "warmup_steps": 2})
    f = _lr_lambda(cfg)
    # Step n runs at f(n - 1): linear warm-up, the peak, a cosine down to decay_lr at the last step.
    assert [f(0), f(1), f(2)] == pytest.approx([0.5, 1.0, 1.0])
    assert f(11) == pytest.approx(0.1) and f(50) == pytest.approx(0.1)
    values = [f(s) for s in range(2, 12)]
    assert all(a > b for a, b in zip(values, values[1:]))
    assert _lr_lambda(validate_policy_cfg({"type": "act"})) is None

    layer = torch.nn.Linear(2, 1)
    start = layer.weight.detach().clone()
    ema = EMA(layer, 0.9)
    with torch.no_grad():
        layer.weight.add_(1.0)
    ema.update()
    ema.copy_to()
    torch.testing.assert_close(layer.weight.detach(), start + 0.1)
