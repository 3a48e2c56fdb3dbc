"""Code the tests share, one module per concern, imported as ``tests.helpers.<module>``.

Plain functions and classes live here; pytest fixtures stay in the ``conftest.py`` files, where
pytest looks for them. Nothing here is named ``test_*`` (pytest would collect it).

- ``policies``: policies for the rollout loop (the scripted operator, a frozen policy) and randomly
  initialised LeRobot checkpoints;
- ``datasets``: a tiny synthetic bimanual LeRobotDataset;
- ``tiny_vla``: tiny pi0 / pi0.5 / SmolVLA / X-VLA models, fully offline;
- ``videos``: rollout folders with tiny videos, and real simulator episodes, for the judges;
- ``chat_server``: an OpenAI-compatible chat server standing in for a VLM;
- ``policy_server``: observations, a fake policy and misbehaving openpi servers for serving;
- ``people``: a small finished run, the annotation app and a headless browser;
- ``slurm``: a single-node Slurm cluster started for the test;
- ``task_rule_states``: the pinned task-rule states (also the script that recorded them);
- ``worlds``: the bundled world's config, robot, tasks, environments and twins;
- ``libero_replay_check``: a script run by LIBERO's own interpreter (not imported).
"""
