"""Run the CLI with ``python -m skinloc``."""

from skinloc.cli import main

main()
