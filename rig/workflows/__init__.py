"""Workflows of many stages or many sessions: the demo, the campaign."""
