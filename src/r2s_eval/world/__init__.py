"""Worlds as data: a world file (``assets/worlds/<name>/world.yaml``) holds a setup's objects and
tasks (``r2s_eval.sim.tasks``, ``r2s_eval.sim.predicates``); ``python -m r2s_eval.world`` checks one
and shows it (``preview``)."""
