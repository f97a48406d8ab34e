"""Post-processed kinematic solutions: RTKLIB runs and RINEX writing."""
