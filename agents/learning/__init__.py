"""Learned controllers: PPO / SAC training on the batched rigs and the saved policies.

* :mod:`~drill_env.agents.learning.rl`: training configs, :func:`~drill_env.agents.learning.rl.train`
  and :func:`~drill_env.agents.learning.rl.load_policy`;
* :mod:`~drill_env.agents.learning.residual`: policies that learn a correction on a classical base;
* :mod:`~drill_env.agents.learning.warm_start`: behaviour cloning of a classical controller
  before reinforcement learning.
"""
