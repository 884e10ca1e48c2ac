"""Run a controller on the rig: the rig I/O protocol and its wire format
(:mod:`~drill_env.rig.protocol`, :mod:`~drill_env.rig.udp`), an emulated rig behind it
(:mod:`~drill_env.rig.emulator`), observations by the environment's own code
(:mod:`~drill_env.rig.observer`), the safety supervisor (:mod:`~drill_env.rig.supervisor`),
the fixed-period control loop and its record (:mod:`~drill_env.rig.loop`), and a numpy-only
runner for exported policies (:mod:`~drill_env.rig.numpy_policy`).

Nothing is imported here: ``import drill_env.rig`` stays instant."""
