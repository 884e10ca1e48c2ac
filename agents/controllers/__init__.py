"""The classical controllers, each behind stable-baselines3's ``predict`` protocol, and their design.

* :mod:`~drill_env.agents.controllers.base`: the protocol and
  :class:`~drill_env.agents.controllers.base.ControllerSpec` (how a controller reads an
  environment's observation and writes its action);
* :mod:`~drill_env.agents.controllers.open_loop`, :mod:`~drill_env.agents.controllers.pi`,
  :mod:`~drill_env.agents.controllers.torque_feedback`, :mod:`~drill_env.agents.controllers.lqi`,
  :mod:`~drill_env.agents.controllers.angle_feedforward`: the controllers;
* :mod:`~drill_env.agents.controllers.linear_model`, :mod:`~drill_env.agents.controllers.tuning`:
  the design model linearised at an operating point and the gain tuning;
* :mod:`~drill_env.agents.controllers.gains`: gains files and building a controller from one.
"""
