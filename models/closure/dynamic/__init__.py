"""The closure on the dynamic baseline: the paper's reduced model simulated through each run
with friction as a state, and the effects that act inside that simulation.

* :mod:`.forms` -- the driving forms (which measured signals drive, which channel is predicted);
* :mod:`.baseline` -- the simulation and its output-error fit (:func:`~.baseline.fit_dynamic`);
* :mod:`.candidates` -- the in-model effect candidates (the catalogue's mechanisms inside the
  simulation, the empirical curves);
* :mod:`.in_model` -- scoring, shape search and the joint refit of a candidate with the baseline;
* :mod:`.long_run` -- the same search on long runs (windows, warm starts);
* :mod:`.trace` -- the residual trace (which signal the baseline's residual depends on);
* :mod:`.closure` -- the greedy selection with the held-out bootstrap, as the pipeline calls it.
"""
