"""Slow, obviously-correct numpy references of the numba kernels: one module per kernel module, same name."""
