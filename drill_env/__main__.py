"""``python -m drill_env``: the command line, as ``drill-env``."""

from drill_env.cli import app

if __name__ == "__main__":
    app(prog_name="python -m drill_env")
