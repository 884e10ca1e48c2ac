"""
The Gymnasium environment: a random and a trained policy
========================================================

``import drill_env`` registers ``DrillString-v3`` (the braked rig of the paper's
experiments; earlier versions are listed in the environment's version history). Each
episode starts on the open-loop behaviour at an operating point the analysis predicts; the
policy then corrects the amplifier voltage around the operator's set point. Here a random
policy and the committed PPO policy trained from scratch on ``DrillString-v3``
(``results/agents/ppo/``) run the same episode.
"""

# %%
# Make the environment and fix the operating point: 1 V, where the open-loop rig sits on a
# torsional (Hopf) limit cycle.
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

from drill_env.agents.learning.rl import load_policy
from drill_env.agents.registry import policy_path

env = gym.make("DrillString-v3", max_episode_steps=600)  # 30 s at 0.05 s per step
obs, info = env.reset(seed=0, options={"nominal_voltage": 1.0})
print(f"observation {obs.shape}, regime {info['regime']}, target {info['target_speed']:.3f} rad/s")


# %%
# A helper that runs one episode with any ``predict``-style controller (stable-baselines3's
# protocol: every controller in the project has it) and keeps the true lower-disk speed
# from ``info``, which the policy never sees.
def episode(predict, seed=0):
    obs, info = env.reset(seed=seed, options={"nominal_voltage": 1.0})
    t, speed, ret = [], [], 0.0
    done = False
    while not done:
        action = predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        t.append(info["time"])
        speed.append(info["true_state"][2])  # twist, upper speed, lower speed, ...
        ret += reward
        done = terminated or truncated
    return np.array(t), np.array(speed), ret


rng = np.random.default_rng(0)
t_rand, x3_rand, ret_rand = episode(lambda obs: rng.uniform(-1, 1, size=1).astype(np.float32))

# %%
# The committed PPO policy, loaded as the benchmark loads it. ``load_policy`` returns an
# object with the same ``predict``; policies outside ``results/agents/`` load with a
# warning, since a policy file is code (see the how-to on policy files).
ppo = load_policy(policy_path("ppo", "brake"))
t_ppo, x3_ppo, ret_ppo = episode(lambda obs: ppo.predict(obs, deterministic=True)[0])
print(f"return: random policy {ret_rand:.1f}, PPO {ret_ppo:.1f}")

# %%
# The random voltage keeps the string oscillating; the trained policy settles the bit on
# its target speed within a few seconds.
fig, ax = plt.subplots(figsize=(7, 3.2))
ax.plot(t_rand, x3_rand, color="tab:gray", label="random policy")
ax.plot(t_ppo, x3_ppo, color="tab:green", label="PPO (results/agents/ppo)")
ax.axhline(info["target_speed"], color="k", ls="--", lw=1, label="target speed")
ax.set_xlabel("time since the controller was switched on [s]")
ax.set_ylabel("lower-disk speed [rad/s]")
ax.legend(loc="upper right")
fig.tight_layout()

# %%
# The reward's components are in ``info["rewards"]`` after every step:
obs, info = env.reset(seed=0, options={"nominal_voltage": 1.0})
obs, reward, terminated, truncated, info = env.step(ppo.predict(obs, deterministic=True)[0])
print(info["rewards"])
