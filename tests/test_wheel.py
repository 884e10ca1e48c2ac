"""The installed package works from any folder: the wheel carries the committed policies and
configs, and the trained policies are found through one lookup (``--agents-dir``,
``DRILL_ENV_AGENTS_DIR``, the source tree's ``results/agents/``, the installed copy). The
controllers of ``agents/`` install as ``drill_env.agents``, never as a top-level ``agents``
(a name other distributions install)."""

from __future__ import annotations

import csv
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

import drill_env
import drill_env.agents.registry as registry
from drill_env import _cache
from drill_env.agents.commands.train import resolve_config
from drill_env.agents.registry import (
    AGENTS_DIR_ENV,
    LEARNED,
    agents_dir_source,
    default_agents_dir,
    policy_path,
)

ROOT = Path(__file__).resolve().parent.parent
PRESETS = ("brake", "no_brake")


def _plant_policies(root: Path, names) -> None:
    for name in names:
        (root / name).mkdir(parents=True)
        (root / name / "policy.zip").write_bytes(b"stand-in")


def test_lookup_order_env_var_then_checkout_then_packaged(tmp_path, monkeypatch):
    checkout, packaged, env_dir, flag_dir = (tmp_path / d for d in ("checkout", "packaged", "env", "flag"))
    _plant_policies(checkout / "results" / "agents", ["ppo"])
    _plant_policies(packaged, ["ppo"])
    _plant_policies(env_dir, ["ppo"])
    _plant_policies(flag_dir, ["ppo"])
    monkeypatch.setattr(registry, "_ROOT", checkout)
    monkeypatch.setattr(registry, "PACKAGED_AGENTS_DIR", packaged)
    monkeypatch.delenv(AGENTS_DIR_ENV, raising=False)

    # an installed wheel: no pyproject.toml beside the packages, so no source tree
    assert agents_dir_source() == (packaged, "installed package")
    assert policy_path("ppo", "brake") == packaged / "ppo" / "policy.zip"
    # a checkout: its results/agents/
    (checkout / "pyproject.toml").write_text("")
    assert agents_dir_source() == (checkout / "results" / "agents", "source tree")
    # the environment variable before both; an empty one is unset
    monkeypatch.setenv(AGENTS_DIR_ENV, "")
    assert default_agents_dir() == checkout / "results" / "agents"
    monkeypatch.setenv(AGENTS_DIR_ENV, str(env_dir))
    assert agents_dir_source() == (env_dir, AGENTS_DIR_ENV)
    assert policy_path("ppo", "brake") == env_dir / "ppo" / "policy.zip"
    # --agents-dir before everything
    assert policy_path("ppo", "brake", flag_dir) == flag_dir / "ppo" / "policy.zip"


def test_a_missing_policy_names_its_file_and_a_command_that_works_anywhere(tmp_path, monkeypatch):
    monkeypatch.setattr(registry, "_ROOT", tmp_path / "site-packages")
    monkeypatch.setattr(registry, "PACKAGED_AGENTS_DIR", tmp_path / "packaged")
    monkeypatch.delenv(AGENTS_DIR_ENV, raising=False)
    _plant_policies(tmp_path / "packaged", ["ppo"])  # the braked rig's only
    with pytest.raises(ValueError) as err:
        policy_path("ppo", "no_brake")
    msg = str(err.value)
    assert str(tmp_path / "packaged" / "ppo_no_brake" / "policy.zip") in msg
    assert "installed package" in msg
    # no --out into the installed package: train's fresh run folder, then --agents-dir
    assert "`drill-env train --algo ppo --config ppo_no_brake` and pass the folder" in msg
    # a folder of the user's own: train straight into it
    mine = tmp_path / "mine"
    monkeypatch.setenv(AGENTS_DIR_ENV, str(mine))
    with pytest.raises(
        ValueError,
        match=rf"from {AGENTS_DIR_ENV}.*--config sac_no_brake --out {re.escape(str(mine / 'sac_no_brake'))}`",
    ):
        policy_path("sac", "no_brake")


def test_config_names_resolve_to_the_shipped_configs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_config(Path("ppo_lqi_clone")) == ROOT / "configs" / "agents" / "ppo_lqi_clone.yaml"
    assert resolve_config(Path("v0/sac_no_brake")) == ROOT / "configs" / "agents" / "v0" / "sac_no_brake.yaml"
    assert (
        resolve_config(Path("experiments/ppo_from_scratch"))
        == ROOT / "configs" / "agents" / "experiments" / "ppo_from_scratch.yaml"
    )
    # a file of that name in the current folder is the user's own config
    (tmp_path / "ppo").write_text("algo: ppo\n")
    assert resolve_config(Path("ppo")) == Path("ppo")
    # a path is left to the loader, which names the missing file
    assert resolve_config(Path("elsewhere/ppo.yaml")) == Path("elsewhere/ppo.yaml")
    with pytest.raises(
        ValueError, match=r"config: no file 'pop' and no config of that name \(names: .*\bppo_lqi_clone, "
    ):
        resolve_config(Path("pop"))
    with pytest.raises(ValueError, match="no config of that name"):
        resolve_config(Path("controllers"))  # the gains file is no training config


def test_the_wheel_lists_every_policy_the_benchmark_runs_by_default():
    force = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["hatch"]["build"]["targets"][
        "wheel"
    ]["force-include"]
    committed = ROOT / "results" / "agents"
    for algo in LEARNED:
        for preset in PRESETS:
            path = policy_path(algo, preset, committed).relative_to(ROOT)
            assert force.get(path.as_posix()) == f"drill_env/_{path.as_posix()}", path
            summary = path.parent / "training_summary.json"
            assert force.get(summary.as_posix()) == f"drill_env/_{summary.as_posix()}", summary
    for source in force:
        assert (ROOT / source).exists(), source


needs_hatchling = pytest.mark.skipif(
    importlib.util.find_spec("hatchling") is None,
    reason="the build backend hatchling is not installed (pip install hatchling)",
)


def _build(source: Path, target: str, out: Path) -> Path:
    """Build ``target`` (``wheel`` or ``sdist``) of the project in ``source`` with hatchling,
    offline (about a second)."""
    subprocess.run(
        [sys.executable, "-m", "hatchling", "build", "--target", target, "--directory", str(out)],
        cwd=source, check=True, capture_output=True,
    )  # fmt: skip
    (path,) = out.glob("drill_env-*.whl" if target == "wheel" else "drill_env-*.tar.gz")
    return path


def _wheel_files(wheel: Path) -> list[str]:
    with zipfile.ZipFile(wheel) as zf:
        return zf.namelist()


def _check_controllers_inside_the_package(names: list[str]) -> None:
    assert len(names) == len(set(names))
    top_level = {n.split("/")[0] for n in names}
    assert top_level - {"drill_env"} == {f"drill_env-{drill_env.__version__}.dist-info"}, top_level
    installed = {n.removeprefix("drill_env/agents/") for n in names if n.startswith("drill_env/agents/")}
    sources = {p.relative_to(ROOT / "agents").as_posix() for p in (ROOT / "agents").rglob("*.py")}
    assert installed == sources
    assert {
        "__init__.py",
        "learning/rl.py",
        "commands/train.py",
        "evaluation/benchmark/__init__.py",
        "controllers/lqi.py",
    } <= installed


@needs_hatchling
def test_the_wheel_has_the_controllers_as_drill_env_agents_and_no_top_level_agents(tmp_path):
    names = _wheel_files(_build(ROOT, "wheel", tmp_path / "wheel"))
    _check_controllers_inside_the_package(names)
    # the same wheel from the source distribution, which has no drill_env/agents link
    sdist = _build(ROOT, "sdist", tmp_path / "sdist")
    with tarfile.open(sdist) as tf:
        members = tf.getnames()
        (top,) = {m.split("/")[0] for m in members}
        assert f"{top}/agents/learning/rl.py" in members and f"{top}/drill_env/agents" not in members
        tf.extractall(tmp_path / "unpacked", filter="data")
    wheel = _build(tmp_path / "unpacked" / top, "wheel", tmp_path / "wheel2")
    assert sorted(_wheel_files(wheel)) == sorted(names)
    # the installed package keys its compiled kernels as the checkout does
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(tmp_path / "installed")
    assert _cache.source_hash(tmp_path / "installed" / "drill_env") == _cache.source_hash()


@pytest.mark.slow
@needs_hatchling
def test_the_installed_wheel_runs_the_benchmark_from_any_folder(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
         "--no-index", "--wheel-dir", str(wheels), str(ROOT)],
        check=True,
    )  # fmt: skip
    (wheel,) = wheels.glob("drill_env-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    assert "drill_env/_results/agents/ppo_lqi_clone_no_brake/policy.zip" in names
    _check_controllers_inside_the_package(sorted(names))
    assert not any(n.startswith("drill_env/_results/agents/v0/") for n in names)

    # A fresh environment with this project from the wheel only; the dependencies come from
    # the running one through a .pth line (a plain path: its own .pth files, e.g. an
    # editable install of the source tree, are not run).
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                               check=True, capture_output=True, text=True).stdout.strip())  # fmt: skip
    # every site folder of the running interpreter (a venv's and any it reaches through a .pth),
    # never the source tree an editable install puts on sys.path
    deps = [p for p in dict.fromkeys(sys.path) if Path(p).name in ("site-packages", "dist-packages")]
    (site / "_dependencies.pth").write_text("".join(f"{d}\n" for d in deps))
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet", "--no-deps", "--no-index",
         str(wheel)],
        check=True,
    )  # fmt: skip

    # another distribution's top-level agents beside it (as openai-agents installs one):
    # nothing of drill-env may import it, the committed policies that pickled their schedules
    # under the former name agents.rl included
    (site / "agents").mkdir()
    (site / "agents" / "__init__.py").write_text('raise ImportError("another distribution\'s agents")\n')

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", AGENTS_DIR_ENV)}
    env["PYTHONWARNINGS"] = "always::UserWarning"  # every UntrustedPolicyWarning reaches stderr
    where = subprocess.run(
        [str(python), "-c", "from pathlib import Path; import drill_env.agents.controllers.gains as g, drill_env.agents.commands.train as t; "
         "print(g.__file__, g.gains_path(), t.resolve_config(Path('ppo_lqi_clone')))"],
        cwd=work, env=env, check=True, capture_output=True, text=True,
    ).stdout.split()  # fmt: skip
    assert len(where) == 3 and all(Path(p).resolve().is_relative_to(site.resolve()) for p in where), where

    # the learned policies on both rigs, a tuned classical controller, the open-loop reference
    out = work / "bench"
    run = subprocess.run(
        [str(env_dir / "bin" / "drill-env"), "benchmark", "--quick", "--controllers", "open_loop,lqi,ppo_lqi_clone,sac_robust",
         "--voltages", "1.0", "--workers", "2", "--no-timeseries", "--out", "bench"],
        cwd=work, env=env, capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    assert "UntrustedPolicyWarning" not in run.stderr, run.stderr
    with open(out / "benchmark.csv") as f:
        rows = list(csv.DictReader(f))
    done = {(r["controller"], r["preset"]) for r in rows if not r.get("error")}
    assert done == {(c, p) for c in ("open_loop", "lqi", "ppo_lqi_clone", "sac_robust") for p in PRESETS}, (
        rows
    )
    summary = (out / "summary.md").read_text()
    assert "_results/agents/ppo_lqi_clone_no_brake/policy.zip" in summary  # the installed copy
    # nothing was written into the source tree or looked up there
    assert not (work / "results").exists()
    shutil.rmtree(env_dir)
