"""Layout of the distributed integrator's buffers: status codes, rows of the work array,
slots of the statistics and error-info vectors (constants only; shared by
:mod:`capstan.models.distributed.integrator`, :mod:`capstan.models.distributed.linsolve` and the kernels)."""

from __future__ import annotations

OK = 0
ERR_SLACK = 1
ERR_NEWTON = 2
ERR_NONFINITE = 3
ERR_PARAM = 4       # a per-node parameter out of range (checked by the model's step kernel)

# rows of the work array
(W_Y0, W_Z1, W_Z2, W_PSI, W_K1, W_F, W_M, W_ATOL, W_DEL, W_R, W_E, W_CP, W_ZZ, W_WW,
 W_FS, W_KT, W_JLO, W_JDI, W_JUP, W_KP, W_P1, W_P2, W_HP, W_YI, W_INV) = range(25)
N_WORK = 25
# W_KP: last stage derivative; W_P1, W_P2: stage increments Z1 - Y0 and Z2 - Z1 of the last
# accepted step; W_HP[0]: that step's size [s] (0 = none). Zeroed by the model's reset.
# W_YI: interpolated state (dense output). W_CP, W_INV, W_WW: factors of M - hg J left by
# distributed_linsolve.solve for its sweep.

# stats slots
S_STEPS, S_RHS, S_REJECT, S_NEWTON_FAIL, S_H, S_ETA = range(6)
N_STATS = 6
# info slots for errors: time, segment index, tension
I_T, I_SEG, I_TENSION = range(3)
