"""Schemathesis hooks for ``test_fuzz.py`` (loaded by the CLI through ``SCHEMATHESIS_HOOKS``):
msgpack request bodies (the service's second media type) and msgpack answers decoded for
the schema checks, typed arrays as nested lists."""

from __future__ import annotations

import random
import uuid

import numpy as np
import schemathesis

from mrdem_common.codec import MSGPACK, packb, unpackb

_INT64 = (-(2**63), 2**64)
_chance = random.Random(17)


def _packable(value):
    """Hypothesis' integers beyond 64 bits as floats (msgpack has no bigger integers)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        return value if _INT64[0] <= value < _INT64[1] else float(value)
    if isinstance(value, dict):
        return {k: _packable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_packable(v) for v in value]
    return value


def _listed(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _listed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_listed(v) for v in value]
    return value


@schemathesis.serializer(MSGPACK)
def to_msgpack(context, value) -> bytes:
    return packb(_packable(value))


@schemathesis.deserializer(MSGPACK)
def from_msgpack(context, response):
    return _listed(unpackb(response.content, strict=True))


@schemathesis.hook
def before_call(context, case, **kwargs):
    """Most generated ``Idempotency-Key`` values made unique: hypothesis repeats short keys
    ("0", "null") with other bodies, which the service rightly answers with 422 before the
    request reaches the step. A fifth keep the generated value (its checks get fuzzed too)."""
    headers = case.headers or {}
    if "Idempotency-Key" in headers and _chance.random() < 0.8:
        headers["Idempotency-Key"] = uuid.uuid4().hex
