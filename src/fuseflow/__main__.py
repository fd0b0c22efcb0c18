"""`python -m fuseflow` runs the CLI."""

from fuseflow.cli import main

main()
