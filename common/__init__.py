"""Neutral helpers shared by the engine, the service and the clients (numpy, msgpack, httpx and
the standard library only; never imports ``engine``, ``service`` or ``clients``).

:mod:`common.codec` (the msgpack array codec of the wire format), :mod:`common.rotation`
(unit quaternion → rotation matrix on the host), :mod:`common.serving` (``python -m service``
on a free loopback port, ready). Nothing is imported here, so that importing one module
does not pull in the others' dependencies.
"""
