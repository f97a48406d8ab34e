"""Package data of the simulated devices (the simulated car's DBC)."""
