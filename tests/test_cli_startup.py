"""An instant command line: ``import drill_env`` and every ``--help`` load none of the heavy
libraries (numba, SciPy, NumPy, Gymnasium, torch, matplotlib, ...), and the environments are
still registered with Gymnasium after ``import drill_env``, whichever is imported first.

What is measured here is which modules load, not how long they take: the times are measured
by ``benchmarks/bench_cli.py`` against ``python -c pass`` in the same run."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = (
    "numpy",
    "numba",
    "scipy",
    "gymnasium",
    "torch",
    "pandas",
    "matplotlib",
    "yaml",
    "stable_baselines3",
    "ray",
)


def _python(code: str) -> str:
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_every_help_loads_no_heavy_library():
    out = _python(
        f"""
import json, sys
import typer.main
from typer.testing import CliRunner
from drill_env.cli import app
heavy = set({HEAVY!r})
loaded = lambda: {{m.split(".")[0] for m in sys.modules}} & heavy
found = {{"import drill_env.cli": sorted(loaded())}}
names = list(typer.main.get_command(app).commands)
for args in [["--help"]] + [[n, "--help"] for n in names]:
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, (args, res.output)
    found[" ".join(args)] = sorted(loaded())
print(json.dumps({{"names": names, "found": found}}))
"""
    )
    result = json.loads(out.splitlines()[-1])
    assert {"simulate", "identify", "discrepancy", "benchmark", "train"} <= set(result["names"])
    assert len(result["found"]) == len(result["names"]) + 2
    assert {k: v for k, v in result["found"].items() if v} == {}


def test_the_check_sees_a_heavy_import():
    # the probe the test above relies on: a command that imports NumPy is seen doing so
    out = _python(
        f"import sys, drill_env, numpy; print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))"
    )
    assert out.strip() == "['numpy']"


def test_import_drill_env_is_light_and_its_names_load_on_use():
    out = _python(
        f"""
import sys, drill_env
heavy = set({HEAVY!r})
before = sorted({{m.split(".")[0] for m in sys.modules}} & heavy)
res = drill_env.simulate("brake", u=2.0, t_final=1.0)
print(before, type(res).__name__, "numba" in sys.modules, sorted(set(drill_env.__all__) - set(dir(drill_env))))
"""
    )
    assert out.strip() == "[] SimulationResult True []"


def test_the_environments_are_registered_whichever_is_imported_first():
    outs = []
    for order in ("import drill_env; import gymnasium as gym", "import gymnasium as gym; import drill_env"):
        out = _python(
            f"""
{order}
env = gym.make("DrillString-v3")
obs, _ = env.reset(seed=0)
print(sorted(i for i in gym.registry if i.startswith("DrillString")), env.observation_space.contains(obs))
"""
        )
        outs.append(out.strip())
    from drill_env.envs import ENV_IDS

    assert outs[0] == outs[1] == f"{sorted(ENV_IDS)} True"
