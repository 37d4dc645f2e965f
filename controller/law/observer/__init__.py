"""Estimators the step runs on the devices' signals: the motor velocity from the encoder position and the
torques (:mod:`capstan.controller.law.observer.motor_velocity`)."""
