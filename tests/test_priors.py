import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxabc import Uniform


def test_sample_inside_box_and_uniform():
    prior = Uniform([0.1, 0.01], [0.8, 1.0], names=("sigma", "epsilon"), units=("nm", "zJ"))
    x = np.asarray(prior.sample(jax.random.key(0), 20000))
    assert x.shape == (20000, 2)
    assert np.all(x >= [0.1, 0.01]) and np.all(x <= [0.8, 1.0])
    # Uniform mean (lo+hi)/2 with standard error (hi-lo)/sqrt(12 n); 5 SE.
    se = np.array([0.7, 0.99]) / np.sqrt(12 * 20000)
    assert np.all(np.abs(x.mean(0) - [0.45, 0.505]) < 5 * se)


def test_log_prob_normalised_and_minus_inf_outside():
    prior = Uniform([0.0, 0.0], [2.0, 0.5])
    assert float(prior.log_prob(jnp.array([1.0, 0.25]))) == pytest.approx(-np.log(1.0))
    assert float(prior.log_prob(jnp.array([3.0, 0.25]))) == -np.inf
    assert prior.log_prob(jnp.zeros((5, 3, 2))).shape == (5, 3)


def test_roundtrip_dict():
    prior = Uniform([0.1], [0.8], names=("sigma",), units=("nm",))
    again = Uniform.from_dict(prior.to_dict())
    assert again.names == ("sigma",) and again.units == ("nm",)
    np.testing.assert_allclose(again.high, [0.8])


@pytest.mark.parametrize(
    "low, high, names, match",
    [
        ([0.8], [0.1], ("sigma",), r"prior bounds for 'sigma' are reversed: low=0.8 > high=0.1"),
        ([0.5], [0.5], None, "degenerate"),
        ([np.nan], [1.0], None, "finite"),
        ([0.0, 0.0], [1.0], None, "equal length"),
        ([0.0], [1.0], ("a", "b"), "2 names for 1"),
        ([], [], None, "no parameters"),
    ],
)
def test_bad_bounds_are_clear_errors(low, high, names, match):
    with pytest.raises(ValueError, match=match):
        Uniform(low, high, names=names)
