"""Controllers for the drill-string rig, all behind stable-baselines3's ``predict`` protocol.

* :mod:`drill_env.agents.base`: the protocol and :class:`~drill_env.agents.base.ControllerSpec` (how a
  controller reads an environment's observation and writes its action);
* :mod:`drill_env.agents.open_loop`, :mod:`drill_env.agents.pi`, :mod:`drill_env.agents.torque_feedback`,
  :mod:`drill_env.agents.lqi`: the classical controllers;
* :mod:`drill_env.agents.linear_model`, :mod:`drill_env.agents.tuning`: the nominal design model and the gain
  tuning procedure;
* :mod:`drill_env.agents.rl`: PPO / SAC training and trained policies;
* :mod:`drill_env.agents.evaluation`: the one evaluation path; :mod:`drill_env.agents.benchmark`: the grid;
  :mod:`drill_env.agents.registry`: the one list of the benchmark's controllers, by name;
* :mod:`drill_env.agents.commands`: the ``drill-env`` commands ``tune``, ``train`` and ``benchmark``.
"""
