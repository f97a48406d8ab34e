"""The in-car recording: the Recording, one module per device kind behind DeviceContext, the status board."""
