"""Train / save / reload / run the candidate policies on a tiny synthetic LeRobotDataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from r2s_eval.horizon import Horizon
from r2s_eval.policies import (
    DatasetContractError,
    PolicyConfigError,
    PolicyError,
    load_policy,
    make_lerobot_config,
    train_policy,
    validate_policy_cfg,
)
from r2s_eval.config import candidate_config, candidate_configs
from r2s_eval.errors import DataError
from r2s_eval.utils.io import file_sha256

from tests.helpers.datasets import build_dataset

pytestmark = pytest.mark.timeout(300)

REPO_ID = "test/synthetic_bimanual"
CAMS = ("observation.images.head_left", "observation.images.wrist_left")
HEAD = "observation.images.head_left"


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("policies_data") / "synthetic"
    return build_dataset(
        root, REPO_ID, n_episodes=3, n_steps=20, image_hw=(32, 32), cameras=CAMS
    )


CONF = Path(__file__).resolve().parents[2] / "conf"


def _line_up(line_up: str = "default") -> dict[str, dict]:
    """The candidates of conf/policies/<line_up>.yaml at their own budgets."""
    from omegaconf import OmegaConf

    entries = OmegaConf.to_container(OmegaConf.load(CONF / "policies" / f"{line_up}.yaml"), resolve=True)
    return {name: validate_policy_cfg(dict(cfg, name=name)) for name, cfg in entries.items()}


def _tiny(name: str, **changes) -> dict:
    """A candidate of the ACT / Diffusion line-up shrunk to test size (small images, few steps)."""
    base = {"steps": 6, "batch_size": 8, "log_every": 1, "image_size": [24, 24], "threads": 1}
    base.update(changes)
    return validate_policy_cfg({**_line_up()[name], **base})


@pytest.fixture(scope="module")
def trained(dataset_root, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("policies_ckpt")
    dirs = {}
    dirs["act"] = out / "act"
    train_policy(dataset_root, REPO_ID, _tiny("act", steps=20, lr=1e-3), dirs["act"], seed=0)
    dirs["diffusion"] = out / "diffusion"
    diffusion = _tiny("diffusion", steps=4)
    diffusion["overrides"]["n_obs_steps"] = 2  # exercise the runner's observation history
    train_policy(dataset_root, REPO_ID, diffusion, dirs["diffusion"], seed=0)
    return dirs


def _obs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    obs = {"observation.state": rng.normal(0, 0.1, size=14).astype(np.float32)}
    for cam in CAMS:
        obs[cam] = rng.integers(0, 255, size=(32, 32, 3), dtype=np.uint8)
    return obs


# -- configs ----------------------------------------------------------------------------------


def test_policies_candidates_build_lerobot_configs():
    line_ups = {experiment: candidate_configs(experiment) for experiment in ("smoke", "demo")}
    line_ups["default"] = _line_up("default")
    for candidates in line_ups.values():
        assert "act_weak" in candidates and len(candidates) >= 3
        for name, cfg in candidates.items():
            if cfg["type"] in ("variant", "snapshot"):  # another candidate's weights: nothing to build
                continue
            lr_cfg = make_lerobot_config(cfg)
            assert lr_cfg.pretrained_backbone_weights is None
            if cfg["type"] == "diffusion":
                assert lr_cfg.horizon % 2 ** len(lr_cfg.down_dims) == 0
                assert lr_cfg.horizon - lr_cfg.n_obs_steps + 1 >= cfg["chunk_size"]
                assert lr_cfg.noise_scheduler_type == "DDIM"
            else:
                assert lr_cfg.chunk_size == cfg["chunk_size"] == 25
        # The weak baseline is the same architecture with far fewer optimisation steps (its own
        # training's, or act's own weights that early).
        weak = candidates["act_weak"]
        assert weak.get("steps", weak.get("step")) * 4 <= candidates["act"]["steps"]


def test_policies_paper_line_up_is_the_vla_recipe():
    candidates = candidate_configs("paper")
    assert set(candidates) == {"pi0", "pi05", "smolvla", "xvla"}
    for name, cfg in candidates.items():
        assert cfg["type"] == name and cfg["steps"] >= 10_000 and cfg["batch_size"] == 32
        assert (cfg["lr"], cfg["decay_lr"], cfg["scheduler"], cfg["warmup_steps"]) == (2.5e-5, 2.5e-6, "cosine", 2000)
        assert (cfg["betas"], cfg["ema_decay"]) == ([0.9, 0.95], 0.9999)
        assert (cfg["chunk_size"], cfg["image_size"], len(cfg["image_keys"])) == (25, [224, 224], 4)
        assert cfg["pretrained_path"].startswith("checkpoints/") and cfg["tokenizer_path"].startswith("checkpoints/")
        # Composing needs no checkpoint; building the lerobot config (training) names what is missing.
        if not Path(cfg["pretrained_path"]).exists():  # a lab's machine may hold the real ones
            with pytest.raises(PolicyConfigError, match=rf"policies\.{name}\.pretrained_path.*{cfg['pretrained_path']}"):
                make_lerobot_config(cfg)
    assert set(_line_up("vla")) == set(candidates)


def test_policies_unknown_override_key_is_named():
    cfg = candidate_config("act", "smoke")
    cfg["overrides"]["dim_modle"] = 64
    with pytest.raises(PolicyConfigError, match="dim_modle"):
        make_lerobot_config(cfg)
    with pytest.raises(PolicyConfigError, match="stepz"):
        candidate_config("act", "smoke", stepz=3)
    bad = _line_up()["diffusion"]
    bad["overrides"]["horizon"] = 16
    with pytest.raises(PolicyConfigError, match="horizon"):
        make_lerobot_config(bad)


def test_policies_missing_image_key_is_named(dataset_root, tmp_path):
    cfg = _tiny("act", image_keys=["observation.images.head_right"])
    with pytest.raises(DatasetContractError, match="observation.images.head_right"):
        train_policy(dataset_root, REPO_ID, cfg, tmp_path / "run", seed=0)
    assert not (tmp_path / "run").exists()
    with pytest.raises(DataError, match="meta/info.json is missing"):
        train_policy(tmp_path / "nowhere", REPO_ID, _tiny("act"), tmp_path / "run2", seed=0)
    with pytest.raises(PolicyError, match="config.json"):
        load_policy(tmp_path / "no_checkpoint", horizon=Horizon(25, 5))


# -- training ---------------------------------------------------------------------------------


def test_policies_checkpoint_layout_and_loss_falls(trained):
    for name, out in trained.items():
        ckpt = out / "pretrained_model"
        for f in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
            assert (ckpt / f).is_file(), f"{name}: missing {f}"
        # ACT resizes in its (saved, reloadable) preprocessor; Diffusion inside the model.
        has_resize = "image_crop_resize_processor" in (ckpt / "policy_preprocessor.json").read_text()
        assert has_resize == (name == "act")
        assert not [p for p in out.parent.iterdir() if p.name.startswith(".")], "temporary dir left behind"
        log = json.loads((out / "train_log.json").read_text())
        assert log["config"]["type"] == name
        assert log["summary"]["wall_s"] > 0 and all(np.isfinite(e["loss"]) for e in log["losses"])
    losses = [e["loss"] for e in json.loads((trained["act"] / "train_log.json").read_text())["losses"]]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:3]), losses


def test_policies_training_is_deterministic(dataset_root, tmp_path):
    cfg = _tiny("act", steps=3, image_keys=list(CAMS))
    a = train_policy(dataset_root, REPO_ID, cfg, tmp_path / "a", seed=7)
    b = train_policy(dataset_root, REPO_ID, cfg, tmp_path / "b", seed=7)
    la = json.loads((tmp_path / "a" / "train_log.json").read_text())["losses"]
    lb = json.loads((tmp_path / "b" / "train_log.json").read_text())["losses"]
    assert [e["loss"] for e in la] == [e["loss"] for e in lb]
    assert a["final_loss"] == b["final_loss"]
    weights = [tmp_path / run / "pretrained_model" / "model.safetensors" for run in ("a", "b")]
    assert file_sha256(weights[0]) == file_sha256(weights[1])


def test_a_candidates_own_seed_takes_the_place_of_the_experiments(dataset_root, tmp_path):
    # `seed` in the candidate's entry: the training is the one the experiment's seed would give
    # had it been that number, whatever the experiment's is.
    cfg = _tiny("act", steps=2)
    own = train_policy(dataset_root, REPO_ID, {**cfg, "seed": 7}, tmp_path / "own", seed=0)
    experiments = train_policy(dataset_root, REPO_ID, cfg, tmp_path / "experiments", seed=7)
    other = train_policy(dataset_root, REPO_ID, cfg, tmp_path / "other", seed=0)
    assert own["seed"] == experiments["seed"] == 7 and other["seed"] == 0
    weights = {run: file_sha256(tmp_path / run / "pretrained_model" / "model.safetensors")
               for run in ("own", "experiments", "other")}
    assert weights["own"] == weights["experiments"] != weights["other"]
    for bad in (-1, True, 1.5):
        with pytest.raises(PolicyConfigError, match=r"'seed' must be a whole number >= 0 or None"):
            validate_policy_cfg({**cfg, "seed": bad})


def test_a_training_on_a_device_the_machine_lacks_is_refused(dataset_root, tmp_path, monkeypatch):
    # lerobot would quietly train on the CPU and the log would say cuda: refused before any data
    # is read, naming the key. CUDA is hidden so the test means the same on a GPU machine.
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cfg = {**_tiny("act", steps=2), "name": "act"}
    for device in ("cuda", "cuda:1"):
        with pytest.raises(PolicyConfigError, match=r"policies\.act\.device is '%s', but this machine has 0 CUDA" % device):
            train_policy(dataset_root, REPO_ID, {**cfg, "device": device}, tmp_path / device, seed=0)
    with pytest.raises(PolicyConfigError, match=r"policies\.act\.device: 'gpu' is not a torch device"):
        train_policy(dataset_root, REPO_ID, {**cfg, "device": "gpu"}, tmp_path / "gpu", seed=0)
    assert not any(tmp_path.iterdir())


def test_a_snapshot_holds_the_weights_a_training_that_short_ends_with(dataset_root, tmp_path):
    # A constant learning rate: a 2-step training draws the same batches as the first 2 steps of
    # a 5-step one, so the snapshot must be its weights bit for bit; saving it changes nothing
    # in the run that goes on.
    cfg = _tiny("act", steps=5)
    assert cfg["scheduler"] == "constant"
    summary = train_policy(dataset_root, REPO_ID, cfg, tmp_path / "with", seed=3, snapshot_steps=[2])
    train_policy(dataset_root, REPO_ID, {**cfg, "steps": 2}, tmp_path / "short", seed=3)
    train_policy(dataset_root, REPO_ID, cfg, tmp_path / "without", seed=3)
    weights = {run: file_sha256(folder / "pretrained_model" / "model.safetensors") for run, folder in {
        "snapshot": tmp_path / "with" / "snapshots" / "2", "short": tmp_path / "short",
        "with": tmp_path / "with", "without": tmp_path / "without"}.items()}
    assert weights["snapshot"] == weights["short"] != weights["with"] == weights["without"]
    assert summary["snapshot_steps"] == [2]
    runner = load_policy(tmp_path / "with" / "snapshots" / "2", horizon=Horizon(25, 5))
    assert runner.horizon == Horizon(25, 5)  # a checkpoint folder like the training's own
    with pytest.raises(ValueError, match=r"snapshot steps \[5\].*\[1, 5\)"):
        train_policy(dataset_root, REPO_ID, cfg, tmp_path / "late", seed=3, snapshot_steps=[5])
    assert not (tmp_path / "late").exists()


# -- inference --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["act", "diffusion"])
def test_policies_receding_horizon(trained, name):
    runner = load_policy(trained[name], horizon=Horizon(25, 5))
    assert runner.horizon == Horizon(25, 5)
    rng = np.random.default_rng(1)
    first_chunk = None
    for t in range(12):
        action = runner.act(_obs(rng))
        assert action.shape == (14,) and action.dtype == np.float32 and np.isfinite(action).all()
        if t == 0:
            first_chunk = runner.last_chunk.copy()
            assert first_chunk.shape == (25, 14)
        if t < 5:
            np.testing.assert_array_equal(action, first_chunk[t])
        assert runner.model_calls == t // 5 + 1
    assert runner.stats["model_calls"] == 3 and runner.stats["inference_s"] > 0
    runner.reset()
    assert runner.model_calls == 0

    every_step = load_policy(trained[name], horizon=Horizon(10, 1))
    for _ in range(4):
        every_step.act(_obs(rng))
    assert every_step.model_calls == 4 and every_step.last_chunk.shape == (10, 14)


def test_policies_inference_deterministic_for_seed(trained):
    obs_seq = [_obs(np.random.default_rng(i)) for i in range(7)]
    a, b = load_policy(trained["diffusion"], horizon=Horizon(25, 5), seed=3), load_policy(trained["diffusion"], horizon=Horizon(25, 5), seed=3)
    run_a = np.stack([a.act(o) for o in obs_seq])
    np.testing.assert_array_equal(run_a, np.stack([b.act(o) for o in obs_seq]))
    b.reset(seed=4)  # another seed, other diffusion noise
    assert not np.array_equal(run_a, np.stack([b.act(o) for o in obs_seq]))
    a.reset()  # same seed again: the same noise stream
    np.testing.assert_array_equal(run_a, np.stack([a.act(o) for o in obs_seq]))


def test_policies_observation_errors(trained):
    runner = load_policy(trained["act"], horizon=Horizon(25, 5))
    obs = _obs(np.random.default_rng(0))
    del obs[HEAD]
    with pytest.raises(PolicyError, match=HEAD):
        runner.act(obs)
    obs = _obs(np.random.default_rng(0))
    obs[HEAD] = obs[HEAD].astype(np.float32)
    with pytest.raises(PolicyError, match="uint8"):
        runner.act(obs)


def test_policies_episodes_fraction_trains_on_a_subset(dataset_root, tmp_path):
    from r2s_eval.data import open_metadata
    from r2s_eval.policies.data import select_episodes

    meta = open_metadata(dataset_root, REPO_ID)
    assert select_episodes(meta, 1.0) is None
    assert select_episodes(meta, 0.5) == [0, 1]  # ceil(0.5 * 3) of the one task's episodes
    assert select_episodes(meta, 0.01) == [0]  # never an empty task
    summary = train_policy(dataset_root, REPO_ID, _tiny("act", episodes_fraction=0.34), tmp_path / "act", seed=0)
    assert summary["num_episodes"] == 2 and summary["num_frames"] == 40
    with pytest.raises(PolicyConfigError, match="episodes_fraction"):
        from r2s_eval.policies.trained_config import validate_policy_cfg

        validate_policy_cfg(_tiny("act", episodes_fraction=0.0))


def test_policies_a_feature_that_barely_moves_is_normalised_with_the_floor():
    from r2s_eval.policies.data import floor_spread

    stats = {"observation.state": {"mean": np.array([0.5, 0.0], np.float32), "std": np.array([0.3, 2e-6], np.float32),
                                   "min": np.array([0.0, -1e-5], np.float32), "max": np.array([1.0, 1e-5], np.float32),
                                   "q01": np.array([0.01, 0.0], np.float32), "q99": np.array([0.99, 0.0], np.float32)},
             "action": {"mean": np.zeros(2, np.float32), "std": np.full(2, 0.2, np.float32)},
             "observation.images.head_left": {"std": np.zeros((3, 1, 1), np.float32)}}
    features = {"observation.state": {"names": ["left_j1", "right_j1"]}, "action": {"names": ["a", "b"]}}
    floored, which = floor_spread(stats, 0.05, features)
    assert which == {"observation.state": ["right_j1"]}
    state = floored["observation.state"]
    assert state["std"].tolist() == pytest.approx([0.3, 0.05]) and state["std"].dtype == np.float32
    assert state["min"][1] == pytest.approx(-0.05) and state["max"][1] == pytest.approx(0.05)
    assert state["q01"][1] == pytest.approx(-0.05) and state["q99"][1] == pytest.approx(0.05)
    assert state["min"][0] == 0.0 and state["max"][0] == 1.0  # a feature that moves keeps its statistics
    assert floored["action"]["std"].tolist() == pytest.approx([0.2, 0.2])
    assert floored["observation.images.head_left"] is stats["observation.images.head_left"]  # cameras untouched
    assert floor_spread(stats, 0.0, features)[1] == {}


def test_policies_the_training_log_names_the_floored_features(trained):
    summary = json.loads((trained["act"] / "train_log.json").read_text())["summary"]
    assert summary["std_floored"] == {} or set(summary["std_floored"]) <= {"observation.state", "action"}
