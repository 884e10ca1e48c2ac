"""Controllers for the drill-string rig, all behind stable-baselines3's ``predict`` protocol."""
