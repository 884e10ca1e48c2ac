"""The late phase of an off-policy run: other update settings from a fraction of the run on.

A config's ``late_phase`` section (SAC, TQC, CrossQ)::

    late_phase:
      after: 0.5            # from this fraction of total_timesteps on
      batch_size: 2048      # the minibatch of every gradient step
      gradient_steps: 2     # gradient steps per call (with batch_size: the same samples per call)
      tau: 0.005            # the target networks' Polyak step (not CrossQ: no target networks)
      freeze_ent_coef: true # the entropy coefficient held at its value of that moment
      actor_average: 0.01   # a Polyak average of the actor, this step per training call

Each setting left out keeps the run's own. With ``actor_average`` the policy evaluated, checked
and saved from the switch on is the running average of the actor's weights (started from the
actor of that moment, ``avg <- (1 - r) avg + r actor`` after every call of the learner's
``train``), not the actor of the last gradient step: the learner itself trains on as before.
:func:`averaged_actor` swaps the average in for the duration of an evaluation or a save. The switch happens once, at the first env-step at
or after ``after x total_timesteps``; :func:`late_phase_callback` is the SB3 callback that
makes it, used by ``drill-env train`` and ``benchmarks/bench_training.py`` alike.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from drill_env.agents.learning._config import config_section

__all__ = ["LatePhaseConfig", "apply_late_phase", "averaged_actor", "late_phase_callback"]


@dataclass(frozen=True)
class LatePhaseConfig:
    after: float = 0.5
    batch_size: int | None = None
    gradient_steps: int | None = None
    tau: float | None = None
    freeze_ent_coef: bool = False
    actor_average: float | None = None

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
        r = self.actor_average
        if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 < r <= 1):
            raise ValueError(f"late_phase.actor_average: expected a number in (0, 1], got {r!r}")
        settings = (self.batch_size, self.gradient_steps, self.tau, self.freeze_ent_coef, self.actor_average)
        if settings == (None, None, None, False, None):
            raise ValueError(
                "late_phase: changes nothing; set at least one of batch_size, gradient_steps, tau, "
                "freeze_ent_coef, actor_average"
            )

    @classmethod
    def from_any(cls, value: Any) -> LatePhaseConfig | None:
        return config_section(cls, value, "late_phase")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"after": self.after}
        for name in ("batch_size", "gradient_steps", "tau", "actor_average"):
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
            self.average: list[Any] | None = None  # the averaged actor's tensors (actor_average)

        def _on_step(self) -> bool:
            if self.switched is None and self.num_timesteps >= at:
                self.switched = apply_late_phase(self.model, late)
                self.switched["at_timesteps"] = int(self.num_timesteps)
                if late.actor_average is not None:
                    self.average = [p.detach().clone() for p in self.model.actor.parameters()]
                if self.model.verbose:
                    print(f"late phase at {self.num_timesteps} steps: {self.switched}", flush=True)
            elif self.average is not None:
                # _on_step runs once per step of the rigs, before the learner's train call of that
                # step: the average takes in the actor of every call but the last one's
                r = float(late.actor_average)
                for a, p in zip(self.average, self.model.actor.parameters(), strict=True):
                    a.mul_(1.0 - r).add_(p.detach(), alpha=r)
            return True

    return _LatePhase()


@contextmanager
def averaged_actor(model: Any, callback: Any) -> Iterator[None]:
    """Inside: ``model``'s actor holds the average of ``callback`` (a :func:`late_phase_callback`
    with ``actor_average``, after its switch); its own weights are back afterwards. A no-op
    without an average (``callback`` None, no ``actor_average``, or before the switch)."""
    average = getattr(callback, "average", None)
    if average is None:
        yield
        return
    import torch

    params = list(model.actor.parameters())
    own = [p.detach().clone() for p in params]
    with torch.no_grad():
        for p, a in zip(params, average, strict=True):
            p.copy_(a)
    try:
        yield
    finally:
        with torch.no_grad():
            for p, o in zip(params, own, strict=True):
                p.copy_(o)
