"""Neutral helpers shared by the engine, the service and the clients (numpy, msgpack, httpx and
the standard library only; never imports ``engine``, ``service`` or ``clients``).

:mod:`mrdem_common.codec` (the msgpack array codec of the wire format),
:mod:`mrdem_common.rotation` (unit quaternion → rotation matrix on the host),
:mod:`mrdem_common.serving` (``python -m service`` on a free loopback port, ready),
:mod:`mrdem_common.lazy` (a package's names imported on first use).
Nothing is imported here, so that importing one module does not pull in the others'
dependencies. Named apart from a generic ``common`` so that a user's own ``common.py``
cannot shadow it.
"""
