"""Bring-up of a rig capstan has not been told about: check, calibrate, identify, tune
(``capstan rig bringup``, docs/bring-up.md)."""
