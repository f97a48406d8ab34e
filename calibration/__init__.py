"""Pure numerical calibration routines over numpy arrays (no devices, files or CLI)."""
