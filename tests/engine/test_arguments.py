"""engine.arguments: the shared argument checks and limits."""

import numpy as np
import pytest

from engine.arguments import check_epsilon, coordinate_limit
from engine.errors import InvalidArgumentError


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_coordinate_limit_is_a_value_of_its_dtype(dtype):
    limit = coordinate_limit(dtype)
    assert float(dtype(limit)) == limit  # a kernel comparing in dtype sees the same value


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_squared_differences_within_the_limit_stay_finite(dtype):
    limit = dtype(coordinate_limit(dtype))
    with np.errstate(over="raise"):
        gap = dtype(limit - (-limit))
        squared = gap * gap * dtype(3)  # |p - q|² over three coordinates
    assert np.isfinite(squared)


def test_epsilon_beyond_the_limit_is_refused():
    limit = coordinate_limit(np.float32)
    assert check_epsilon(limit, 2, np.float32, "eps").dtype == np.float32
    with pytest.raises(InvalidArgumentError, match="too large for float32"):
        check_epsilon(2.0 * limit, 2, np.float32, "eps")
