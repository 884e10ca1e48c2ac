"""The late phase of an off-policy run: other update settings from a fraction of the run on.

A config's ``late_phase`` section (SAC, TQC, CrossQ)::

    late_phase:
      after: 0.5            # from this fraction of total_timesteps on
      batch_size: 2048      # the minibatch of every gradient step
      gradient_steps: 2     # gradient steps per call (with batch_size: the same samples per call)
      tau: 0.005            # the target networks' Polyak step (not CrossQ: no target networks)
      freeze_ent_coef: true # the entropy coefficient held at its value of that moment

Each setting left out keeps the run's own. The switch happens once, at the first env-step at
or after ``after x total_timesteps``; :func:`late_phase_callback` is the SB3 callback that
makes it, used by ``drill-env train`` and ``benchmarks/bench_training.py`` alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from drill_env.agents.learning._config import config_section

__all__ = ["LatePhaseConfig", "apply_late_phase", "late_phase_callback"]


@dataclass(frozen=True)
class LatePhaseConfig:
    after: float = 0.5
    batch_size: int | None = None
    gradient_steps: int | None = None
    tau: float | None = None
    freeze_ent_coef: bool = False

    def __post_init__(self) -> None:
        a = self.after
        if isinstance(a, bool) or not isinstance(a, (int, float)) or not 0 < a < 1:
            raise ValueError(f"late_phase.after: expected a fraction of the run in (0, 1), got {a!r}")
        for name in ("batch_size", "gradient_steps"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise ValueError(f"late_phase.{name}: expected an integer >= 1, got {v!r}")
        t = self.tau
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 < t <= 1):
            raise ValueError(f"late_phase.tau: expected a number in (0, 1], got {t!r}")
        if not isinstance(self.freeze_ent_coef, bool):
            raise ValueError(f"late_phase.freeze_ent_coef: expected true or false, got {self.freeze_ent_coef!r}")
        if (self.batch_size, self.gradient_steps, self.tau, self.freeze_ent_coef) == (None, None, None, False):
            raise ValueError(
                "late_phase: changes nothing; set at least one of batch_size, gradient_steps, tau, freeze_ent_coef"
            )

    @classmethod
    def from_any(cls, value: Any) -> LatePhaseConfig | None:
        return config_section(cls, value, "late_phase")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"after": self.after}
        for name in ("batch_size", "gradient_steps", "tau"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        if self.freeze_ent_coef:
            out["freeze_ent_coef"] = True
        return out


def apply_late_phase(model: Any, late: LatePhaseConfig) -> dict[str, Any]:
    """Switch ``model`` (an SB3 off-policy learner) to the late settings; returns what was set."""
    import torch

    done: dict[str, Any] = {}
    if late.batch_size is not None:
        model.batch_size = done["batch_size"] = late.batch_size
    if late.gradient_steps is not None:
        model.gradient_steps = done["gradient_steps"] = late.gradient_steps
    if late.tau is not None:
        if not hasattr(model, "tau"):
            raise ValueError(f"late_phase.tau: {type(model).__name__} has no target networks")
        model.tau = done["tau"] = float(late.tau)
    if late.freeze_ent_coef and getattr(model, "ent_coef_optimizer", None) is not None:
        value = torch.exp(model.log_ent_coef.detach()).reshape(())
        model.ent_coef_tensor = value.clone()
        model.ent_coef_optimizer = None  # SB3 then uses ent_coef_tensor, and saves it
        done["ent_coef"] = float(value)
    return done


def late_phase_callback(late: LatePhaseConfig | None, total_timesteps: int) -> Any:
    """The SB3 callback switching to ``late`` at ``late.after x total_timesteps`` env-steps
    (``None`` without a late phase)."""
    if late is None:
        return None
    from stable_baselines3.common.callbacks import BaseCallback

    at = late.after * total_timesteps

    class _LatePhase(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.switched: dict[str, Any] | None = None

        def _on_step(self) -> bool:
            if self.switched is None and self.num_timesteps >= at:
                self.switched = apply_late_phase(self.model, late)
                self.switched["at_timesteps"] = int(self.num_timesteps)
                if self.model.verbose:
                    print(f"late phase at {self.num_timesteps} steps: {self.switched}", flush=True)
            return True

    return _LatePhase()
