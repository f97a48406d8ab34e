"""Evaluation of a session: validate, rollover, steering, calibrate, report (a session in, results out)."""
