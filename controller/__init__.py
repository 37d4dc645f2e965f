"""The real-time part of capstan: discrete LDO, friction feedforward, safety stage
(Numba step functions on preallocated arrays), the 1 kHz loop and the daemon."""
