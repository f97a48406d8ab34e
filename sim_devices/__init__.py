"""The world in a box: vehicle-dynamics model with ground truth, sensor models and simulated devices.

Simulated devices speak the real wire protocols on real transports; they use the codecs in
``drivers`` and never take a shortcut around a driver.
"""
