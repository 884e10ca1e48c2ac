"""``python -m drill_env``: the command line, as ``drill-env`` (the same Ctrl-C handling)."""

from drill_env.cli import main

if __name__ == "__main__":
    main(prog_name="python -m drill_env")
