"""Vehicle-dynamics model, tyre model, scenarios and the ground truth they produce."""
