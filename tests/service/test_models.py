"""The HTTP models: arrays typed by shape and kind the same from JSON lists and from
msgpack's typed binary, non-finite values and non-unit quaternions named by their element's
path, the problem's field errors, and a scene specification that validates back to itself
once normalised (the store keeps the normalised one)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pydantic import BaseModel, ValidationError

from mrdem_common.codec import JSON, MSGPACK, packb
from service.deps import validated
from service.errors import Unprocessable
from service.models import (
    CONTACTS_QUERY,
    QUATERNION_TOLERANCE,
    ColumnarQuery,
    PerPairQuery,
    SceneSpec,
    Shape,
    field_errors,
)
from service.models.arrays import Points, Quaternions
from service.models.problems import joined


class Holder(BaseModel):
    points: Points
    turns: Quaternions | None = None


def _errors(payload) -> list[dict]:
    with pytest.raises(ValidationError) as error:
        Holder.model_validate(payload)
    return field_errors(error.value.errors())


finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 6), st.just(3)), elements=finite))
def test_points_from_lists_and_from_arrays_are_the_same(points):
    for given_as in (points, points.tolist(), points.astype(np.float32)):
        out = Holder.model_validate({"points": given_as}).points
        assert out.dtype == np.float64 and out.shape == points.shape
        np.testing.assert_array_equal(out, np.asarray(given_as, np.float64).reshape(points.shape))


@given(
    hnp.arrays(np.float64, st.tuples(st.integers(1, 5), st.just(3)), elements=finite),
    st.data(),
)
def test_a_non_finite_value_is_named_by_its_element(points, data):
    row = data.draw(st.integers(0, len(points) - 1))
    column = data.draw(st.integers(0, 2))
    points[row, column] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    for given_as in (points, points.tolist()):
        [error] = _errors({"points": given_as})
        assert error == {
            "path": f"points[{row}][{column}]",
            "message": "must hold finite numbers only",
        }


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ([[0, 0]], "must have shape (n, 3), got [1, 2]"),
        ([0, 0, 0], "must have shape (n, 3), got [3]"),
        ("points", "must be an array of numbers of shape (n, 3)"),
        ([[True, False, True]], "must be an array of numbers"),
        ([[0, 0, "a"]], "must be an array of numbers"),
        ([[0, 0], [0, 0, 0]], "must be an array of numbers"),
        ({"x": 1}, "must be an array of numbers"),
    ],
)
def test_wrong_shapes_and_kinds_say_what_is_expected(value, words):
    [error] = _errors({"points": value})
    assert error["path"] == "points" and words in error["message"]


@given(st.floats(-2 * QUATERNION_TOLERANCE, 2 * QUATERNION_TOLERANCE), st.integers(0, 3))
def test_quaternions_near_unit_are_normalised_others_are_named(offset, row):
    turns = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    turns[row] *= 1.0 + offset
    if abs(offset) <= 0.999 * QUATERNION_TOLERANCE:
        out = Holder.model_validate({"points": [], "turns": turns}).turns
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=0, atol=1e-15)
    elif abs(offset) >= 1.001 * QUATERNION_TOLERANCE:
        [error] = _errors({"points": [], "turns": turns})
        assert error["path"] == f"turns[{row}]"
        assert error["message"].startswith("must be a unit quaternion (w, x, y, z)")


def test_integer_arrays_refuse_fractions():
    spec = Shape(None, integer=True)
    assert spec.validate([1, 2]).dtype == np.int64
    with pytest.raises(Exception, match="must be an array of integers"):
        spec.validate([1.5])


def test_problems_name_each_field_and_read_as_one_detail():
    with pytest.raises(Unprocessable) as error:
        validated(
            SceneSpec,
            json.dumps(
                {"bodies": [{"mesh": "m", "fixed": 1, "density": 1, "mass": 2}], "dt": "x"}
            ).encode(),
            JSON,
        )
    errors = error.value.extra["errors"]
    assert {"path": "bodies[0].fixed", "message": "must be true or false, got 1"} in errors
    assert {"path": "dt", "message": "must be a number, got 'x'"} in errors
    assert error.value.detail == joined(errors)
    assert "bodies[0].fixed must be true or false, got 1" in error.value.detail
    with pytest.raises(Unprocessable, match=r"^the body must be an object"):
        validated(SceneSpec, b"[1, 2]", JSON)
    with pytest.raises(Unprocessable, match="colour is not a field of this request"):
        validated(SceneSpec, b'{"bodies": [{"mesh": "m"}], "colour": 1}', JSON)


def _columns(n: int, rng) -> dict:
    q = rng.normal(size=(n, 4))
    return {
        "meshes": ["m0", "m1"],
        "a": rng.integers(0, 2, n),
        "b": rng.integers(0, 2, n),
        "position_a": rng.normal(size=(n, 3)),
        "orientation_a": q / np.linalg.norm(q, axis=1, keepdims=True),
        "position_b": rng.normal(size=(n, 3)),
        "orientation_b": np.tile([1.0, 0, 0, 0], (n, 1)),
        "kernel": "exact",
    }


@pytest.mark.parametrize("n", [1, 7, 100])
def test_json_and_msgpack_bodies_validate_to_the_same_query(n):
    body = _columns(n, np.random.default_rng(n))
    as_json = validated(CONTACTS_QUERY, json.dumps(body, default=np.ndarray.tolist).encode(), JSON)
    as_msgpack = validated(CONTACTS_QUERY, packb(body), MSGPACK)
    assert isinstance(as_json, ColumnarQuery) and isinstance(as_msgpack, ColumnarQuery)
    for name in ("a", "b", "position_a", "orientation_a", "position_b", "orientation_b"):
        np.testing.assert_array_equal(getattr(as_json, name), getattr(as_msgpack, name))
    assert as_json.kernel == as_msgpack.kernel == "exact"
    pairs = {"pairs": [{"a": "m0", "b": "m1", "pose_b": {"position": [0, 0, 1]}}]}
    assert isinstance(validated(CONTACTS_QUERY, packb(pairs), MSGPACK), PerPairQuery)


def test_columns_must_agree_with_each_other():
    body = _columns(3, np.random.default_rng(0))
    body["position_b"] = body["position_b"][:2]
    with pytest.raises(Unprocessable, match="position_b must have 3 rows"):
        validated(CONTACTS_QUERY, packb(body), MSGPACK)
    body = _columns(3, np.random.default_rng(0))
    body["b"] = np.array([0, 1, 2])
    with pytest.raises(Unprocessable, match=r"b holds indices outside meshes \(0 … 1\)"):
        validated(CONTACTS_QUERY, packb(body), MSGPACK)


vectors = st.lists(finite, min_size=3, max_size=3)
bodies = st.fixed_dictionaries(
    {"mesh": st.text("abcdef0123", min_size=1, max_size=8)},
    optional={
        "position": vectors,
        "velocity": vectors,
        "fixed": st.booleans(),
        "density": st.floats(1e-3, 1e4),
        "epsilon": st.one_of(st.just("auto"), st.floats(1e-6, 1.0)),
    },
)
specs = st.fixed_dictionaries(
    {"bodies": st.lists(bodies, min_size=1, max_size=4)},
    optional={
        "planes": st.lists(st.fixed_dictionaries({}, optional={"point": vectors}), max_size=2),
        "dt": st.floats(1e-6, 1e-2),
        "scheme": st.sampled_from(["explicit", "implicit-midpoint", "multiscale"]),
        "separation_speed": st.one_of(st.none(), st.floats(1e-3, 10.0)),
        "contact_model": st.fixed_dictionaries(
            {}, optional={"law": st.sampled_from(["paper", "linear", "hertz"])}
        ),
    },
)


@given(specs)
def test_a_normalised_specification_validates_back_to_itself(spec):
    normalised = SceneSpec.model_validate(spec).normalised()
    assert SceneSpec.model_validate(normalised).normalised() == normalised
    assert json.loads(json.dumps(normalised)) == normalised  # plain JSON for the store
    body = normalised["bodies"][0]
    assert ("mass" in body) != ("density" in body)
