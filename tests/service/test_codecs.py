"""service.codecs: the HTTP side of the wire format on top of mrdem_common.codec, interoperating
with the client's side (clients/codec.py) byte for byte."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from clients import codec as client_codec
from mrdem_common import codec
from service import codecs
from service.errors import BadRequest, UnsupportedMediaType

PAYLOADS = [
    {"positions": np.arange(12.0).reshape(4, 3), "mesh": 3, "name": "ball", "flag": True},
    {"q": np.eye(4, dtype=np.float32)[:, ::-1], "i": np.arange(5, dtype=np.uint32)},
    {"empty": np.zeros((0, 3)), "nested": [{"b": np.array([True, False])}, np.int64(2)]},
    [np.float64(0.5), None, "x", {"big": np.arange(3, dtype=">i8")}],
]


@pytest.mark.parametrize("payload", PAYLOADS)
def test_the_service_and_the_client_write_the_same_bytes(payload):
    body = codecs.encode_msgpack(payload)
    assert body == client_codec.encode(payload, client_codec.MSGPACK) == codec.packb(payload)
    for read in (
        codecs.decode(body, "application/msgpack"),
        codecs.decode(body, "application/x-msgpack; charset=binary"),
        client_codec.decode(body, "application/msgpack"),
    ):
        assert codec.packb(read) == body  # what one side writes, the other reads back


def test_unreadable_arrays_are_400_with_the_codec_message():
    bad = msgpack.packb(msgpack.ExtType(codec.NDARRAY_EXT, msgpack.packb(["<f8", [2], b"x"])))
    with pytest.raises(BadRequest, match="needs 16 bytes, got 1"):
        codecs.decode(bad, codecs.MSGPACK)
    other = msgpack.packb(msgpack.ExtType(7, b""))
    with pytest.raises(BadRequest, match="unknown msgpack extension type 7"):
        codecs.decode(other, codecs.MSGPACK)
    assert client_codec.decode(other, client_codec.MSGPACK) == msgpack.ExtType(7, b"")


def test_malformed_msgpack_and_other_media_are_refused():
    with pytest.raises(BadRequest, match="malformed msgpack"):
        codecs.decode(b"\xc1", codecs.MSGPACK)
    with pytest.raises(BadRequest, match="malformed msgpack"):
        codecs.decode(msgpack.packb({1: 2}), codecs.MSGPACK)
    with pytest.raises(BadRequest, match="non-finite number NaN"):
        codecs.decode(b'{"a": NaN}', codecs.JSON)
    with pytest.raises(UnsupportedMediaType, match="text/csv"):
        codecs.decode(b"1,2", "text/csv")


def test_json_bodies_carry_arrays_as_lists():
    payload = {"a": np.arange(4).reshape(2, 2), "x": np.float32(0.5)}
    assert client_codec.encode(payload, client_codec.JSON) == b'{"a": [[0, 1], [2, 3]], "x": 0.5}'
    assert codecs.decode(client_codec.encode(payload, client_codec.JSON), codecs.JSON) == {
        "a": [[0, 1], [2, 3]],
        "x": 0.5,
    }
