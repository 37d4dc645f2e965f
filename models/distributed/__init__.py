"""The distributed full-order model (paper eqs 2-13) and its stiff integrator.

``model`` (:class:`~capstan.models.distributed.model.DistributedModel`), ``params``
(parameters, boundary modes, results), ``rhs`` (right-hand side and Jacobian),
``integrator`` / ``linsolve`` / ``work`` (the Radau IIA integrator, its Newton algebra and
buffers), ``dense`` (error-controlled runs across sample times), ``kernels`` (compiled
entry points) and ``ode`` (the equations for general ODE solvers).

May import :mod:`capstan.models.transmission` and :mod:`capstan.models.common`.
"""
