"""Reproduction of the paper's Figs. 6-11 and 13 on the simulated rig: ``experiment``
(the command's driver), ``common`` (settings, routings, plant runs), ``figs_*`` (one
module per group of figures), ``recommend`` and ``report``.
"""
