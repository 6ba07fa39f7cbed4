"""Run the CLI with ``python -m skinloc``."""

from skinloc.cli.main import main

main()
