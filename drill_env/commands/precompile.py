"""``drill-env precompile``: compile every kernel into the on-disk cache."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("precompile")
    def precompile() -> None:
        """Compile the simulator and the environments into the cache, once.

        Run it after installing or upgrading, before starting many processes at once
        (SB3's SubprocVecEnv, the benchmark's worker pool): they then load the compiled
        kernels instead of each compiling them.
        """
        from drill_env import _cache, _numba  # noqa: F401  # _numba sets the cache directory
        from drill_env.precompile import precompile as run

        typer.echo(f"compiling into {_cache.cache_dir()}", err=True)

        def show(part: str, seconds: float) -> None:
            typer.echo(f"  {part:<20s} {seconds:6.1f} s", err=True)

        total = sum(run(progress=show).values())
        typer.echo(f"done in {total:.1f} s")
