"""Worlds as data: the ``world`` config group (``conf/world/<name>.yaml``) holds a setup's cameras,
objects and tasks (``r2s_eval.sim.tasks``, ``r2s_eval.sim.predicates``); ``python -m r2s_eval.world``
checks one and shows it (``preview``). ``judging`` builds a judge that knows a world's tasks and
robot, and writes the descriptions and verdicts of the judging stages."""
