"""The compiled all-pairs kernel (md.lj.native) against the pure-JAX one and the neighbour list.

Both kernels compute the same float32 sums in a different order, so they agree to rounding: the
tolerances are a few float32 ulps of the largest force, not fitted to a result.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from md import helium, lj
from md.lj import native

pytestmark = pytest.mark.skipif(
    not native.available(), reason=f"compiled kernel unavailable: {native.unavailable_reason()}"
)

N, SIDE, CUTOFF = 32, 2.4, 0.639  # the helium cpu preset's size: the cutoff reaches past L / 4


def _batch(b: int, seed: int = 0):
    key_p, key_s, key_e, key_l = jax.random.split(jax.random.PRNGKey(seed), 4)
    position = jax.random.uniform(key_p, (b, N, 3), dtype=jnp.float32)
    # Across the helium prior and past it: sigma > r_c makes the potential a repulsive step.
    sigma = jax.random.uniform(key_s, (b,), jnp.float32, 0.2, 0.8)
    epsilon = jax.random.uniform(key_e, (b,), jnp.float32, 0.01, 0.4)
    side = SIDE * jax.random.uniform(key_l, (b, 3), jnp.float32, 0.9, 1.1)
    return position, side, sigma, epsilon


@pytest.mark.parametrize("shifted", [False, True])
@pytest.mark.parametrize("b", [1, 5, 16, 37])  # lane groups full, partial, several
def test_native_matches_pure_jax_all_pairs(b: int, shifted: bool) -> None:
    position, side, sigma, epsilon = _batch(b, seed=b)
    energy_fn = lj.make_energy_fn(CUTOFF, "shifted" if shifted else "plain")
    params = lj.LJParams(sigma, epsilon, jnp.zeros(b), jnp.ones(b))

    def reference(p, s, prm):
        box = jnp.diag(s)
        f, st = energy_fn.force_and_strain(p, box, idx=None, params=prm)
        return f, st, energy_fn(p, box, idx=None, params=prm)

    f_ref, s_ref, e_ref = jax.jit(jax.vmap(reference))(position, side, params)
    call = jax.jit(jax.vmap(lambda p, s, sg, ep: native.all_pairs(p, s, sg, ep, CUTOFF, shifted)))
    f, s, e = call(position, side, sigma, epsilon)
    scale = np.max(np.abs(np.asarray(f_ref)), axis=(1, 2), keepdims=True)
    assert np.all(scale > 0)
    np.testing.assert_allclose(np.asarray(f) / scale, np.asarray(f_ref) / scale, atol=2e-6)
    # Energies and strains are sums of terms of both signs: compare on the scale of the terms.
    e_scale = np.maximum(np.abs(np.asarray(e_ref)), np.asarray(epsilon))
    np.testing.assert_allclose(np.asarray(e) / e_scale, np.asarray(e_ref) / e_scale, atol=1e-5)
    s_scale = np.maximum(np.abs(np.asarray(s_ref)), np.asarray(epsilon))
    np.testing.assert_allclose(np.asarray(s) / s_scale, np.asarray(s_ref) / s_scale, atol=1e-5)


def test_native_under_nested_vmap_and_unbatched_is_the_same_call() -> None:
    position, side, sigma, epsilon = _batch(12)

    def call(p, s, sg, ep):
        return native.all_pairs(p, s, sg, ep, CUTOFF)

    flat = jax.jit(jax.vmap(call))(position, side, sigma, epsilon)
    nested = jax.jit(jax.vmap(jax.vmap(call)))(
        position.reshape(3, 4, N, 3), side.reshape(3, 4, 3), sigma.reshape(3, 4), epsilon.reshape(3, 4)
    )
    single = jax.jit(call)(position[7], side[7], sigma[7], epsilon[7])
    for a, b in zip(flat, nested, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b).reshape(a.shape))
    # One system alone shares no lane group: the same per-system arithmetic, bit for bit.
    for a, b in zip(flat, single, strict=True):
        np.testing.assert_array_equal(np.asarray(a)[7], np.asarray(b))


def test_native_forces_match_the_neighbor_list_and_the_energy_gradient() -> None:
    position = _batch(3, seed=4)[0]
    energy_fn = lj.make_energy_fn(CUTOFF)
    p0, box = position[0], jnp.eye(3, dtype=jnp.float32) * SIDE
    spec = lj.NeighborSpec("sparse", N, CUTOFF, 0, N * N, N * (N - 1) // 2, N)
    nbrs = lj.build_neighbor_list(spec, p0, box)
    params = lj.LJParams(jnp.float32(0.2556), jnp.float32(0.085), jnp.float32(0.0), jnp.float32(1.0))
    f_list, s_list = energy_fn.force_and_strain(p0, box, idx=nbrs.idx, params=params)
    grad = jax.grad(energy_fn)(p0, box, params=params)
    f, s, e = native.all_pairs(p0, jnp.full(3, SIDE), params.sigma_nm, params.epsilon_kj_mol, CUTOFF)
    scale = float(np.max(np.abs(np.asarray(f_list))))
    assert scale > 0
    np.testing.assert_allclose(np.asarray(f) / scale, np.asarray(f_list) / scale, atol=2e-6)
    np.testing.assert_allclose(np.asarray(f) / scale, -np.asarray(grad) / scale, atol=1e-4)
    np.testing.assert_allclose(float(s), float(s_list), rtol=1e-4)
    np.testing.assert_allclose(float(e), float(energy_fn(p0, box, idx=nbrs.idx, params=params)), rtol=1e-4)


def test_helium_engine_uses_native_and_matches_the_xla_engine() -> None:
    """Same start, same steps: trajectories agree until rounding differences grow (chaos)."""
    preset = helium.get_preset("cpu")
    config = preset.engine_config()
    fast = lj.LJEngine(config)
    slow = lj.LJEngine(dataclasses.replace(config, force_kernel="xla"))
    assert (fast.force_kernel, slow.force_kernel) == ("native", "xla")
    thetas = jnp.asarray([[0.2556, 0.141], [0.3, 0.3], [0.45, 0.05]], jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(3), 3)

    def go(engine):
        def one(key, theta):
            params = helium._params(theta)
            carry = engine.init(key, params)
            carry, thermo = engine.run(carry, params, 2, 1, engine.thermo)
            return carry.md.position, thermo

        return jax.jit(jax.vmap(one))(keys, thetas)

    (p_fast, t_fast), (p_slow, t_slow) = go(fast), go(slow)
    d = np.array(p_fast - p_slow)
    d -= np.round(d)
    assert np.max(np.abs(d)) < 1e-4  # two blocks of steps: still rounding-level apart
    for name in ("potential", "virial", "pressure", "temperature"):
        a, b = np.asarray(getattr(t_fast, name)), np.asarray(getattr(t_slow, name))
        scale = np.maximum(np.abs(b), 1e-3 * np.max(np.abs(b)) + 1e-6)
        np.testing.assert_allclose(a / scale, b / scale, atol=2e-3, err_msg=name)


def test_force_kernel_choice_is_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    config = helium.get_preset("cpu").engine_config()
    with pytest.raises(ValueError, match="force_kernel must be one of"):
        dataclasses.replace(config, force_kernel="fortran")
    with pytest.raises(ValueError, match="neighbour list"):
        lj.LJEngine(dataclasses.replace(config, use_neighbor_list=True, force_kernel="native"))
    monkeypatch.setenv("JAXABC_NATIVE_KERNELS", "0")
    native._load.cache_clear()
    try:
        assert native.unavailable_reason() == "disabled by JAXABC_NATIVE_KERNELS=0"
        with pytest.raises(ValueError, match="disabled by JAXABC_NATIVE_KERNELS"):
            lj.LJEngine(dataclasses.replace(config, force_kernel="native"))
        assert lj.LJEngine(config).force_kernel == "xla"  # auto falls back, and says so
    finally:
        monkeypatch.delenv("JAXABC_NATIVE_KERNELS")
        native._load.cache_clear()
    assert native.available()


def test_instruction_set_is_recorded_and_a_baseline_can_be_chosen(monkeypatch: pytest.MonkeyPatch) -> None:
    """-march=native results are CPU-specific: provenance names the instruction set, and
    JAXABC_NATIVE_MARCH builds (and caches) for a baseline instead."""
    monkeypatch.delenv("JAXABC_NATIVE_MARCH", raising=False)
    here = native.instruction_set()
    assert here["march"] == "native" and isinstance(here["resolved"], str) and here["resolved"]
    native_path = native.library_path()
    monkeypatch.setenv("JAXABC_NATIVE_MARCH", "x86-64-v2")
    baseline = native.instruction_set()
    assert baseline["march"] == baseline["resolved"] == "x86-64-v2"
    assert native.library_path() != native_path
    assert "-march=x86-64-v2" in native._flags()
