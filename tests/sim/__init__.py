"""Tests of the vehicle-dynamics simulator against physics with known answers."""
