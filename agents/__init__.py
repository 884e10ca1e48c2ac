"""Controllers for the drill-string rig, all behind stable-baselines3's ``predict`` protocol.

* :mod:`drill_env.agents.controllers`: the classical controllers and their design on the
  design model;
* :mod:`drill_env.agents.learning`: PPO / SAC training, residual and warm-started policies,
  :func:`~drill_env.agents.learning.rl.load_policy`;
* :mod:`drill_env.agents.evaluation`: the one evaluation path, the plants, the benchmark grid
  and its reports;
* :mod:`drill_env.agents.registry`: the one list of the benchmark's controllers, by name;
* :mod:`drill_env.agents.commands`: the ``drill-env`` commands ``tune``, ``train``,
  ``benchmark`` and ``sim-to-real``.

Dependencies run one way: controllers <- learning <- evaluation; the registry names them all.
"""
