"""The environment page, generated from ``DrillStringEnv``'s docstring (as Gymnasium's are).

The class docstring is written in Markdown with Gymnasium's sections (Description, Action
Space, Observation Space, Rewards, Starting State, Episode End, Arguments, Version
History). This writes ``_generated/env.md`` before the sources are read: a table of the
registered ids with what each is, then the docstring with its Sphinx roles
(``:class:`~x.Y```) turned into MyST roles. ``reference/environment.md`` includes it.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

ROLE = re.compile(r":(class|func|meth|mod|data|attr|exc):`([^`]+)`")


def docstring_markdown(doc: str) -> str:
    """The env's docstring as MyST Markdown: roles converted, code examples marked as excerpts."""
    text = inspect.cleandoc(doc)
    text = ROLE.sub(lambda m: "{py:" + m.group(1) + "}`" + m.group(2) + "`", text)
    # A code example in the docstring is an excerpt (it assumes `import gymnasium`).
    text = re.sub(r"^```python", "<!-- excerpt -->\n```python", text, flags=re.M)
    return text + "\n"


def ids_table() -> str:
    import gymnasium

    from drill_env.envs import ENV_IDS, ENV_VERSIONS

    lines = [
        "| id | rig preset | observation | steps per episode |",
        "|---|---|---|---|",
    ]
    for env_id, preset in ENV_IDS.items():
        spec = gymnasium.spec(env_id)
        size = 8 if ENV_VERSIONS[env_id] == 0 else 13
        lines.append(
            f"| `{env_id}` | `{preset}` | v{ENV_VERSIONS[env_id]}, `Box(({size},), float32)` | "
            f"{spec.max_episode_steps} |"
        )
    lines += [
        "",
        "Every id has a native vector version, `gymnasium.make_vec(id, num_envs=N)`, that steps all",
        "rigs in one compiled call ({py:class}`drill_env.envs.vector.DrillStringVectorEnv`).",
    ]
    return "\n".join(lines) + "\n"


def render_frame(path: Path) -> None:
    """One ``rgb_array`` frame of ``DrillString-v3``: 5 s open loop at 2 V (stick-slip)."""
    import gymnasium
    import matplotlib.pyplot as plt
    import numpy as np

    env = gymnasium.make("DrillString-v3", render_mode="rgb_array")
    obs, _ = env.reset(seed=0, options={"nominal_voltage": 2.0})
    for _ in range(100):
        obs, *_ = env.step(np.array([obs[7]], dtype=np.float32))  # the nominal voltage / 5 V
    plt.imsave(path, env.render())
    env.close()


def write_env_page(app) -> None:  # noqa: ANN001 (Sphinx application)
    from drill_env.envs.drill_string import DrillStringEnv

    frame = Path(app.srcdir) / "_generated" / "env_frame.png"
    frame.parent.mkdir(parents=True, exist_ok=True)
    if not frame.is_file():
        render_frame(frame)
    body = [
        "![DrillString-v3 rendered (rgb_array): the two disks and the string, with the speeds of the"
        " last seconds; 5 s open loop at 2 V](../_generated/env_frame.png)",
        "",
        "| | |",
        "|---|---|",
        "| Action space | `Box(-1.0, 1.0, (1,), float32)` (the voltage / 5 V) |",
        "| Observation space | `Box(low, high, (13,), float32)` in v1, `(8,)` in v0 |",
        "| Import | `import drill_env` registers the ids below |",
        "| Class | {py:class}`drill_env.envs.drill_string.DrillStringEnv` |",
        "",
        ids_table(),
        docstring_markdown(DrillStringEnv.__doc__ or ""),
    ]
    text = "\n".join(body)
    out = Path(app.srcdir) / "_generated" / "env.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_env_page)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
