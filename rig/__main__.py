"""``python -m rig``."""

from rig.cli.main import main

main()
