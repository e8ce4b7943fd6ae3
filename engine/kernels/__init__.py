"""Numba kernels: functions over flat arrays and scalars only.

Nothing here validates, allocates unbounded outputs or imports the host layer;
see :mod:`engine.distance` for the host API that calls these kernels.
"""
