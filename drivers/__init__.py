"""Device drivers (CiA 402 motor over CANopen, Xsens MTi IMU, load-cell amplifier)
and simulated devices that speak the same wire protocols."""
