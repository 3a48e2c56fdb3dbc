"""What a slot gets from a model call does not depend on the other slots of the call.

The rollout loop runs many episodes side by side and asks the policy for all of them at once;
an episode's actions (so its trajectory and video) must be the same bytes whatever ran beside
it. A batched forward rounds differently from a single one (other kernel paths), so in-process
policies call the model with a fixed number of rows and a slot in a fixed row: these tests
catch a torch or lerobot update after which that no longer holds."""

from __future__ import annotations


import numpy as np
import pytest

from r2s_eval.policies.lerobot_policy import load_lerobot_policy
from r2s_eval.utils.numerics import deterministic_torch

from tests.helpers.policies import save_random_policy

CAMERAS = ["head_left", "wrist_right"]
HW = (48, 48)


@pytest.fixture(scope="module", params=["act", "diffusion"])
def folder(request, tmp_path_factory):
    return save_random_policy(tmp_path_factory.mktemp(request.param), CAMERAS, HW, request.param)


def _observations(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [{"observation.state": rng.normal(0, 0.2, 14).astype(np.float32),
             **{f"observation.images.{c}": rng.integers(0, 256, (*HW, 3), dtype=np.uint8) for c in CAMERAS}}
            for _ in range(n)]


def _chunks(policy, slots: list[int], observations: list[dict], steps: int = 2) -> list[np.ndarray]:
    """`steps` queries of every slot (reset with its own seed first), as the rollout loop asks."""
    for s in slots:
        policy.reset(s, 1000 + s)
    out = []
    for step in range(steps):
        for s, obs in zip(slots, observations):
            policy.observe(s, obs)
        out.append(policy.predict_chunks(slots, [policy.select(o) for o in observations]))
        observations = [{**o, "observation.state": o["observation.state"] + 0.01 * (step + 1)} for o in observations]
    return out


def test_a_slots_chunks_do_not_depend_on_the_slots_beside_it(folder):
    deterministic_torch(1)
    policy = load_lerobot_policy(folder, call_batch=4)
    mine = _observations(1, seed=0)
    for slot in (0, 3, 6):  # rows 0 and 3 of the call, and row 2 again for another slot number
        alone = _chunks(policy, [slot], mine)
        # Beside 1, 3 and 6 other slots (6: more than one call's rows), at different places.
        for n_others, place in ((1, 0), (3, 2), (6, 5)):
            others = _observations(n_others, seed=n_others)
            other_slots = [s for s in range(20, 40) if s % 4 != slot % 4][:n_others]
            slots = other_slots[:place] + [slot] + other_slots[place:]
            batch = others[:place] + mine + others[place:]
            together = _chunks(policy, slots, batch)
            for step, (a, b) in enumerate(zip(alone, together)):
                assert np.array_equal(a[0], b[place]), (
                    f"slot {slot} beside {n_others} others: chunk {step} differs by {np.abs(a[0] - b[place]).max()}")


def test_slots_sharing_a_row_are_called_apart_and_get_their_own_chunks(folder):
    deterministic_torch(1)
    policy = load_lerobot_policy(folder, call_batch=4)
    obs = _observations(3, seed=5)
    alone = [_chunks(policy, [s], [o])[0][0] for s, o in zip((1, 5, 9), obs)]  # all in row 1
    together = _chunks(policy, [1, 5, 9], obs)[0]
    for a, b in zip(alone, together):
        assert np.array_equal(a, b)
    assert together.shape[0] == 3 and not np.array_equal(together[0], together[1])


def test_act_batched_calls_give_lerobots_own_chunks_from_one_backbone_pass(tmp_path):
    """In a fixed-shape call, ACT's ResNet (its batch norms folded into its convolutions) runs once
    over every camera's images, not once per camera as lerobot's forward does; the chunks are
    lerobot's own up to rounding."""
    import torch

    deterministic_torch(1)
    folder = save_random_policy(tmp_path, CAMERAS, HW, "act")
    policy = load_lerobot_policy(folder, call_batch=3)
    observations = _observations(3, seed=7)
    passes = []
    first_conv = policy.policy.model.backbone.conv1  # runs once per real pass of the ResNet
    hook = first_conv.register_forward_hook(lambda module, args, out: passes.append(args[0].shape[0]))
    try:
        for s in range(3):
            policy.reset(s, s)
        chunks = policy.predict_chunks([0, 1, 2], observations)
    finally:
        hook.remove()
    assert passes == [3 * len(CAMERAS)]  # one pass, every camera's rows

    lerobots = load_lerobot_policy(folder)  # the model as lerobot built it
    with torch.no_grad():
        batch = lerobots.preprocess(observations)
        expected = lerobots.postprocessor(lerobots.policy.predict_action_chunk(batch)).numpy()
    assert not np.array_equal(chunks, expected)  # other kernels ran ...
    np.testing.assert_allclose(chunks, expected, rtol=1e-4, atol=1e-5)  # ... to the same actions
