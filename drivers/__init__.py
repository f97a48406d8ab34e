"""Wire protocols, transports and device sessions (NovAtel, CAN, DAQ, optical sensor).

Knows nothing of sessions, files or MCAP, and never imports ``rig`` or ``sim_devices``.
"""
