"""Controllers for the drill-string rig, all behind stable-baselines3's ``predict`` protocol.

* :mod:`agents.base`: the protocol and :class:`~agents.base.ControllerSpec` (how a
  controller reads an environment's observation and writes its action);
* :mod:`agents.open_loop`, :mod:`agents.pi`, :mod:`agents.torque_feedback`,
  :mod:`agents.lqi`: the classical controllers;
* :mod:`agents.linear_model`, :mod:`agents.tuning`: the nominal design model and the gain
  tuning procedure;
* :mod:`agents.rl`: PPO / SAC training and trained policies;
* :mod:`agents.evaluation`: the one evaluation path; :mod:`agents.benchmark`: the grid;
  :mod:`agents.registry`: the one list of the benchmark's controllers, by name;
* :mod:`agents.commands`: the ``drill-env`` commands ``tune``, ``train`` and ``benchmark``.
"""
