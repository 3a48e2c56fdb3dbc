"""Tiny pi0 / pi0.5 policies through lerobot's own classes: train, predict, save, reload, offline.

lerobot's pi configs cannot describe a small model (the smallest is ~4B parameters), so `tiny_vla`
swaps the network sizes for the duration of the tests; see its module docstring.
"""

from __future__ import annotations

import json
import socket

import pytest
import torch

from tests.helpers import tiny_vla as tv

pytestmark = pytest.mark.timeout(300)

CHUNK = 10
N_ACTION_STEPS = 5
DIM = 14


@pytest.fixture(scope="module")
def tiny_env(tmp_path_factory):
    with tv.tiny_pi_env(tmp_path_factory.mktemp("private_hf") / "hub") as env:
        yield env
        assert env.network_attempts == []


def _seeded_loss(policy, batch, seed: int = 0) -> torch.Tensor:
    # The flow-matching loss draws noise and time; a fixed seed makes before/after comparable.
    torch.manual_seed(seed)
    loss, info = policy.forward(batch)
    assert set(info) >= {"loss", "loss_per_dim"} and len(info["loss_per_dim"]) == DIM
    return loss


def _seeded_chunk(policy, batch, seed: int = 1) -> torch.Tensor:
    torch.manual_seed(seed)
    return policy.predict_action_chunk(batch)


def test_tokenizer_served_from_private_cache(tiny_env):
    from transformers import AutoTokenizer

    tok = AutoTokenizer.from_pretrained(tv.PALIGEMMA_TOKENIZER)
    assert len(tok) <= tiny_env.dims.vocab_size
    ids = tok("pick up the cube\n")["input_ids"]
    assert ids[0] == tok.bos_token_id == 2 and tok.pad_token_id == 0
    assert tok.decode(ids, skip_special_tokens=True) == "pick up the cube\n"
    # Unseen characters fall back to byte tokens instead of <unk>.
    assert tok.unk_token_id not in tok("zébra ✓")["input_ids"]
    assert tiny_env.hub_cache.joinpath("models--google--paligemma-3b-pt-224", "refs", "main").is_file()


@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_train_predict_save_reload(policy_type, tiny_env, tmp_path):
    policy, pre, post = tv.make_tiny_pi(policy_type, chunk_size=CHUNK, n_action_steps=N_ACTION_STEPS)
    assert type(policy).__name__ == {"pi0": "PI0Policy", "pi05": "PI05Policy"}[policy_type]
    # The substitution is active: the stock smallest model has ~4e9 parameters.
    assert tv.parameter_count(policy) < 1_000_000
    vlm = policy.model.paligemma_with_expert.paligemma
    assert vlm.config.text_config.vocab_size == tiny_env.dims.vocab_size

    batch = pre(tv.synthetic_batch(2, state_dim=DIM, action_dim=DIM, chunk_size=CHUNK))
    tokens = batch["observation.language.tokens"]
    assert tokens.shape == (2, policy.config.tokenizer_max_length)
    assert int(tokens.max()) < tiny_env.dims.vocab_size
    assert batch["observation.language.attention_mask"].dtype == torch.bool
    assert batch["action"].shape == (2, CHUNK, DIM)
    if policy_type == "pi05":
        # pi0.5 writes the quantile-normalised, discretised state into the prompt.
        assert batch["task"][0].startswith("Task: ") and "State: " in batch["task"][0]
        assert not bool(batch["observation.language.attention_mask"].all(dim=1).any()), "prompt truncated"

    policy.train()
    before = {k: v.detach().clone() for k, v in policy.state_dict().items()}
    loss_before = _seeded_loss(policy, batch).item()
    optimizer = torch.optim.AdamW(policy.parameters(), lr=1e-3)
    for _ in range(3):
        loss = _seeded_loss(policy, batch)
        assert torch.isfinite(loss)
        optimizer.zero_grad()
        loss.backward()
        grads = [p.grad for p in policy.parameters() if p.grad is not None]
        assert grads and all(torch.isfinite(g).all() for g in grads)
        optimizer.step()
    loss_after = _seeded_loss(policy, batch).item()
    assert torch.isfinite(torch.tensor(loss_after))
    assert loss_after < loss_before, (loss_before, loss_after)
    changed = [k for k, v in policy.state_dict().items() if not torch.equal(v, before[k])]
    assert any(k.startswith("model.action_out_proj") for k in changed)
    assert any(".vision_tower." in k for k in changed) and any(".gemma_expert." in k for k in changed)

    obs = tv.synthetic_batch(1, state_dim=DIM, action_dim=DIM, chunk_size=None, seed=7)
    chunk = _seeded_chunk(policy, pre(obs))
    assert chunk.shape == (1, CHUNK, DIM) and torch.isfinite(chunk).all()
    actions = post(chunk)
    assert actions.shape == (1, CHUNK, DIM) and torch.isfinite(actions).all()
    # The postprocessor undoes the normalisation, so actions come back in robot units.
    assert not torch.allclose(actions, chunk)

    policy.reset()
    torch.manual_seed(1)
    first = policy.select_action(pre(obs))
    assert first.shape == (1, DIM)
    assert len(policy._action_queue) == N_ACTION_STEPS - 1

    folder = tv.save_tiny_pi(tmp_path / policy_type, policy, pre, post)
    saved_config = json.loads((folder / "config.json").read_text())
    assert saved_config["type"] == policy_type and saved_config["chunk_size"] == CHUNK
    assert (folder / "model.safetensors").is_file()
    assert json.loads((folder / "policy_preprocessor.json").read_text())  # processors saved too

    reloaded, pre2, post2 = tv.load_tiny_pi(folder, check_weights=False)
    assert type(reloaded) is type(policy)
    # PI0Policy / PI05Policy.from_pretrained swallow load errors and return random weights: compare.
    assert tv.state_dict_mismatches(policy.state_dict(), reloaded.state_dict()) == []
    batch2 = pre2(obs)
    assert torch.equal(batch2["observation.language.tokens"], pre(obs)["observation.language.tokens"])
    chunk2 = _seeded_chunk(reloaded, batch2)
    assert torch.equal(chunk2, chunk)
    assert torch.equal(post2(chunk2), actions)
    assert tiny_env.network_attempts == []


def test_build_tiny_pi_other_shapes(tiny_env, tmp_path):
    folder = tv.build_tiny_pi(
        "pi05",
        tmp_path / "pi05_small",
        state_dim=7,
        action_dim=6,
        cameras=("observation.images.front",),
        image_hw=(32, 32),
        chunk_size=4,
        n_action_steps=4,
    )
    policy, pre, post = tv.load_tiny_pi(folder)
    obs = tv.synthetic_batch(
        1,
        state_dim=7,
        action_dim=6,
        chunk_size=None,
        cameras=("observation.images.front",),
        image_hw=(32, 32),
    )
    actions = post(_seeded_chunk(policy, pre(obs)))
    assert actions.shape == (1, 4, 6) and torch.isfinite(actions).all()
    assert policy.config.image_features.keys() == {"observation.images.front"}


def test_silent_random_weights_trap_is_caught(tiny_env, tmp_path):
    from safetensors.torch import load_file, save_file

    folder = tv.build_tiny_pi("pi0", tmp_path / "pi0_broken")
    weights = load_file(folder / "model.safetensors")
    key = "model.action_out_proj.weight"
    weights[key] = torch.zeros(weights[key].shape[0], weights[key].shape[1] + 1)
    save_file(weights, folder / "model.safetensors", metadata={"format": "pt"})

    # lerobot itself only prints a warning and hands back a partly random model...
    policy = tv.policy_class("pi0").from_pretrained(folder)
    assert policy.state_dict()[key].shape != weights[key].shape
    # ...which the helper refuses.
    with pytest.raises(RuntimeError, match="weights did not load"):
        tv.load_tiny_pi(folder)


def test_network_guard_blocks_and_records(tiny_env):
    attempts: list[str] = []
    with tv.no_network(attempts):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            with pytest.raises(OSError, match="blocked"):
                sock.connect(("192.0.2.1", 443))  # TEST-NET-1: never routed
    assert attempts == ["('192.0.2.1', 443)"]
    assert tiny_env.network_attempts == []


def test_substitution_is_scoped():
    from lerobot.policies import pi_gemma
    from lerobot.policies.pi0 import modeling_pi0
    from lerobot.policies.pi05 import modeling_pi05

    # The module fixture may already be active here: check that a nested swap restores what it found.
    names = ("get_gemma_config", "PaliGemmaForConditionalGenerationWithPiGemma", "PiGemmaForCausalLM")
    outer = {(m, n): getattr(m, n) for m in (modeling_pi0, modeling_pi05) for n in names}
    with tv.tiny_pi_models(tv.TinyDims(vlm_width=48)):
        for module in (modeling_pi0, modeling_pi05):
            assert module.get_gemma_config("gemma_2b").width == 48
            assert module.PiGemmaForCausalLM is not pi_gemma.PiGemmaForCausalLM
    assert all(getattr(m, n) is value for (m, n), value in outer.items())
