"""Evaluation: the one path every controller is scored by, and what is built on it.

* :mod:`~drill_env.agents.evaluation.episodes`: one episode and its metrics
  (:func:`~drill_env.agents.evaluation.episodes.evaluate`), the path every run takes;
* :mod:`~drill_env.agents.evaluation.plants`: the plants a controller is evaluated on (the
  nominal rig, plant files, the standard family);
* :mod:`~drill_env.agents.evaluation.benchmark`: the controller x voltage x plant grid, its
  results file and report; :mod:`~drill_env.agents.evaluation.robustness`: the worst case over
  plants; :mod:`~drill_env.agents.evaluation.timeseries`: time-series figures;
* :mod:`~drill_env.agents.evaluation.sim_to_real`: the worked example from recordings to a
  corrected model and controllers designed on it.
"""
