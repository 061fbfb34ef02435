"""The compiled all-pairs LJ kernel for small boxes on CPU: an XLA FFI custom call.

XLA's CPU code for the (N, N) all-pairs broadcast of :mod:`md.lj.dense` materialises every
intermediate array and vectorises poorly (measured in ``engine_throughput_small_system.json``).
``kernels/lj_all_pairs.cc`` does the same arithmetic with one SIMD lane per system of the batch
(:func:`jax.ffi.ffi_call` with ``vmap_method="broadcast_all"``, so it runs inside ``jit``, ``vmap``
and ``scan`` like any primitive). It is compiled on first use with the machine's C++ compiler
(``-O3 -march=native``) into ``~/.cache/jaxabc/native`` (``$XDG_CACHE_HOME`` respected), keyed on the
source, compiler, jax version and CPU flags; ``scripts/setup.sh`` builds it ahead
(``md.lj.native.main``).

``-march=native`` makes the kernel's floating-point results (FMA contraction, vector width)
specific to the CPU family that built it: results made with it reproduce bitwise only on the
same instruction set, which :func:`instruction_set` names and benchmark provenance records.
``JAXABC_NATIVE_MARCH=x86-64-v3`` (or any ``-march`` value) builds for a documented baseline
instead, the same on every CPU that has it.

Where it cannot be used (no compiler, a GPU backend, float64, or ``JAXABC_NATIVE_KERNELS=0``)
the engine falls back to the pure-JAX kernel: :func:`unavailable_reason` says why, and
``LJEngine.force_kernel`` names the kernel an engine uses.  Only forces, the strain derivative
and the energy are provided: the kernel has no JAX derivative rule (the engine needs none).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from md.lj.config import Array

__all__ = [
    "SOURCE",
    "TARGET",
    "all_pairs",
    "available",
    "build",
    "instruction_set",
    "library_path",
    "unavailable_reason",
]

SOURCE = Path(__file__).with_name("kernels") / "lj_all_pairs.cc"
TARGET = "jaxabc_lj_all_pairs"
_BASE_FLAGS = ("-O3", "-fno-math-errno", "-std=c++17", "-shared", "-fPIC", "-w")
_DISABLE = "JAXABC_NATIVE_KERNELS"
_MARCH = "JAXABC_NATIVE_MARCH"


def _march() -> str:
    """The ``-march`` the kernel is built for: ``native`` unless ``JAXABC_NATIVE_MARCH`` says."""
    return os.environ.get(_MARCH, "").strip() or "native"


def _flags() -> tuple[str, ...]:
    return (_BASE_FLAGS[0], f"-march={_march()}", *_BASE_FLAGS[1:])


@functools.lru_cache(maxsize=4)
def _resolved_march(compiler: str | None, march: str) -> str:
    """What ``-march=native`` means on this CPU (GCC/Clang print it), else ``march`` itself."""
    if compiler is None or march != "native":
        return march
    try:
        out = subprocess.run(
            [compiler, "-march=native", "-Q", "--help=target"], capture_output=True, text=True, timeout=30
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return march
    for line in out.splitlines():
        words = line.split()
        if len(words) == 2 and words[0] == "-march=":
            return words[1]
    return march


def instruction_set() -> dict[str, object]:
    """The instruction set the kernel is (or would be) built for, for provenance.

    Returns ``{"march": requested, "resolved": what native means here (e.g. "znver3"),
    "simd": the vector extensions the CPU reports (avx2, avx512f, fma, ...)}``.  Results made
    with a ``native`` kernel reproduce bitwise only where ``resolved`` and ``simd`` match.
    """
    flags = set(_cpu_flags().split())
    simd = sorted(flags & {"sse4_2", "avx", "avx2", "fma", "avx512f", "avx512dq", "avx512vl", "neon", "asimd"})
    return {"march": _march(), "resolved": _resolved_march(_compiler(), _march()), "simd": simd}


class NativeBuildError(RuntimeError):
    """The C++ compiler failed on the kernel (its message is included)."""


def _compiler() -> str | None:
    return os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")


def _cpu_flags() -> str:
    # -march=native code is specific to the CPU it was built on: the flags join the cache key.
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


def library_path() -> Path:
    """Where the compiled library for this source, compiler, jax and CPU lives (may not exist)."""
    compiler = _compiler() or "none"
    key = hashlib.sha256()
    for part in (SOURCE.read_bytes(), compiler.encode(), jax.__version__.encode(), " ".join(_flags()).encode()):
        key.update(part)
    key.update(_cpu_flags().encode())
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "jaxabc" / "native"
    return root / f"lj_all_pairs-{key.hexdigest()[:16]}.so"


def build(force: bool = False) -> Path:
    """Compile the kernel (unless already built) and return the library's path.

    Raises :class:`NativeBuildError` if there is no C++ compiler or it fails.  The library is
    written to a temporary name and renamed, so concurrent builds (process pools) are safe.
    """
    path = library_path()
    if path.exists() and not force:
        return path
    compiler = _compiler()
    if compiler is None:
        raise NativeBuildError("no C++ compiler (set CXX, or install g++)")
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        out = Path(tmp) / path.name
        cmd = [compiler, *_flags(), f"-I{jax.ffi.include_dir()}", str(SOURCE), "-o", str(out)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise NativeBuildError(f"{' '.join(cmd)} failed:\n{proc.stderr[-4000:]}")
        os.replace(out, path)
    return path


@functools.lru_cache(maxsize=1)
def _load() -> str | None:
    """Build, load and register the kernel once per process; None on success, else why not."""
    if os.environ.get(_DISABLE, "1").strip().lower() in ("0", "false", "no", "off"):
        return f"disabled by {_DISABLE}={os.environ[_DISABLE]}"
    if not sys.platform.startswith("linux") and sys.platform != "darwin":
        return f"no build recipe for {sys.platform}"
    try:
        lib = ctypes.cdll.LoadLibrary(str(build()))
        jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(lib.LjAllPairs), platform="cpu")
    except (NativeBuildError, OSError, AttributeError) as exc:
        return f"the kernel could not be built or loaded: {exc}"
    return None


def unavailable_reason() -> str | None:
    """None if the compiled kernel is usable in this process, else a sentence saying why not."""
    if jax.default_backend() != "cpu":
        return f"the compiled kernel runs on CPU; the default backend is {jax.default_backend()}"
    if jax.config.read("jax_enable_x64"):
        return "the compiled kernel is float32; jax_enable_x64 is on"
    return _load()


def available() -> bool:
    """Whether :func:`all_pairs` can run here (builds the kernel on first call)."""
    return unavailable_reason() is None


def all_pairs(
    position: Array, side: Array, sigma: Array, epsilon: Array, cutoff_nm: float, shifted: bool = False
) -> tuple[Array, Array, Array]:
    """All-pairs LJ forces, strain derivative and energy of one system (vmappable).

    Parameters
    ----------
    position : Array, shape (N, 3), float32
        Fractional coordinates in the unit cube.
    side : Array, shape (3,)
        Orthorhombic box sides, nm.
    sigma, epsilon : Array, shape ()
        nm, kJ/mol.
    cutoff_nm : float
        Pairs at r >= r_c do not interact (LAMMPS ``lj/cut``).
    shifted : bool
        Subtract the pair energy at r_c from the energy (forces are unchanged).

    Returns
    -------
    (Array (N, 3), Array (), Array ())
        Forces (kJ/mol/nm), dU/d(eps) for the isotropic strain r -> (1 + eps) r (kJ/mol), and
        U (kJ/mol): the quantities of :func:`md.lj.dense.all_pairs_force_and_strain` and of
        the engine's ``energy_fn``, equal to float32 rounding.  Raises ``RuntimeError`` if the
        kernel is unavailable (see :func:`unavailable_reason`).
    """
    why = unavailable_reason()
    if why is not None:
        raise RuntimeError(why)
    position = jnp.asarray(position, jnp.float32)
    f32 = jnp.float32
    out = (
        jax.ShapeDtypeStruct(position.shape, f32),
        jax.ShapeDtypeStruct(position.shape[:-2], f32),
        jax.ShapeDtypeStruct(position.shape[:-2], f32),
    )
    call = jax.ffi.ffi_call(TARGET, out, vmap_method="broadcast_all")
    force, strain, energy = call(
        position,
        jnp.asarray(side, f32),
        jnp.asarray(sigma, f32),
        jnp.asarray(epsilon, f32),
        cutoff=np.float32(cutoff_nm),
        shifted=np.int32(bool(shifted)),
    )
    return force, strain, energy


def main() -> int:
    """Build the kernel and say where it is, or why it is not (``scripts/setup.sh`` calls it)."""
    try:
        path = build()
    except NativeBuildError as exc:
        print(f"native LJ kernel: not built ({exc}); the engine uses its pure-JAX kernel", file=sys.stderr)
        return 0
    why = unavailable_reason()
    print(f"native LJ kernel: {path}" + ("" if why is None else f" (not used here: {why})"))
    return 0
