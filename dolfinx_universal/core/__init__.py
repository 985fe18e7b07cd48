"""Shared machinery of every stage: array helpers, collective errors, compiled kernels, Lagrange
geometry."""
