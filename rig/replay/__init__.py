"""HIL replay of a session's CAN frames onto a bus."""
