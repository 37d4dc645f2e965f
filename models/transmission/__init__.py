"""The transmission and what it drives, in closed form.

``routing`` (curvature profile), ``pretension`` (field and averaged pretension, eqs
23-25), ``reduced`` (the reduced model, eqs 14-21), ``baselines`` (the predictors of
Fig. 11), ``lugre`` (LuGre friction for comparison) and ``link`` (the instrumented link).

May import :mod:`capstan.models.common` only.
"""
