"""Numba kernels: functions over flat arrays and scalars only, split as the host is.

``geometry/`` (triangle distances, welding), ``trees/`` (surrogate fit, tree build),
``collision/`` (broad phase, traversal, batches, contact merging) and ``dynamics/``
(contact forces, motion); ``jit.py`` holds the compilation options and the cache key.
Nothing here validates, allocates unbounded outputs or imports the host layer; each
sub-package of :mod:`engine` calls the kernels of its concern.
"""
