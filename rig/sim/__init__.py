"""The simulated world: the devices' host process, the simulated recording, the comparison with the truth."""
