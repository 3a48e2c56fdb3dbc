"""The receding horizon: one value built from the config, one rule, every loop runs it."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.errors import ConfigError, R2SError
from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import ChunkPolicy, PolicyError, PolicySpec, RecedingHorizon


class _Counting(ChunkPolicy):
    """Chunk k (k = 1, 2, ...) holds actions k*100 + i, i its index in the chunk."""

    name = "counting"
    spec = PolicySpec(cameras=(), action_dim=2, max_chunk=8, uses_state=False)

    def __init__(self, length: int = 8):
        self.calls, self.length = 0, length

    def predict_chunks(self, slots, observations):
        self.calls += 1
        chunk = self.calls * 100 + np.arange(self.length, dtype=np.float32)
        return np.repeat(np.stack([chunk, chunk], axis=1)[None], len(slots), axis=0)


def test_a_horizon_is_built_from_its_config_slice():
    horizon = Horizon.from_config({"chunk": 25, "execute": 5})
    assert horizon == Horizon(chunk=25, execute=5) and horizon.to_dict() == {"chunk": 25, "execute": 5}
    with pytest.raises(AttributeError):
        horizon.chunk = 10  # built once: nobody changes it on the way


@pytest.mark.parametrize(("chunk", "execute", "max_chunk"), [(8, 0, 8), (4, 5, 8), (9, 5, 8)])
def test_the_rule_names_the_policy_and_the_keys(chunk, execute, max_chunk):
    with pytest.raises(ConfigError) as err:
        Horizon(chunk, execute).check(max_chunk, "policy 'act'")
    assert isinstance(err.value, R2SError)
    assert str(err.value) == (f"the receding horizon needs 1 <= rollout.horizon.execute ({execute}) <= "
                              f"rollout.horizon.chunk ({chunk}) <= {max_chunk}, the most actions policy 'act' "
                              f"predicts per call")


def test_without_a_policy_only_execute_against_chunk_is_checked():
    Horizon(25, 25).check(None)
    with pytest.raises(ConfigError, match=r"execute \(6\) <= rollout\.horizon\.chunk \(5\)$"):
        Horizon(5, 6).check(None)


def test_receding_horizon_executes_the_first_actions_of_each_chunk():
    policy = _Counting()
    runner = RecedingHorizon(policy, Horizon(chunk=6, execute=3))
    actions = [runner.act({})[0] for _ in range(7)]
    assert actions == [100, 101, 102, 200, 201, 202, 300] and policy.calls == 3
    assert runner.last_chunk.shape == (6, 2)  # only the chunk the evaluation uses is kept


def test_receding_horizon_checks_the_rule_before_any_call():
    policy = _Counting()
    with pytest.raises(ConfigError, match=r"chunk \(9\) <= 8, the most actions policy 'counting' predicts"):
        RecedingHorizon(policy, Horizon(9, 3))
    assert policy.calls == 0


def test_a_chunk_shorter_than_the_horizon_is_the_policys_fault():
    runner = RecedingHorizon(_Counting(length=4), Horizon(chunk=6, execute=3))
    with pytest.raises(PolicyError, match=r"returned a chunk of shape \(4, 2\), expected at least \(6, 2\)"):
        runner.act({})
