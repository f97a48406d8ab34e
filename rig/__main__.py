"""``python -m rig``."""

from rig.cli.main import main

if __name__ == "__main__":  # not when a spawned process (the simulated devices) imports it
    main()
