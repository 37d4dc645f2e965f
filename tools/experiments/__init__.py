"""Experiments: ``interaction`` (paper §4.5, Fig. 13), ``breakaway`` (breakaway friction
after rests), ``e2e_closure`` (HIL -> close -> HIL) and :mod:`capstan.tools.experiments.paper`
(the paper's figures reproduced).

May import :mod:`capstan.tools.offline` and everything below ``tools``.
"""
