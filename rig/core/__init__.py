"""The core of the rig: topics and schemas, configuration, the time base, quality thresholds and live verdicts."""
