"""Physics and estimation for the capstan tendon-sheath joint: no I/O here.

Routing and pretension, the distributed full-order model, the reduced model and
baselines, the simulated rig, the effect catalogue and identification math.
"""
