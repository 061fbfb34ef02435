"""The host and fused drivers behind :func:`jaxabc.run`.

- :mod:`.context`: the compiled algorithm, the distance function, the simulation recorder;
- :mod:`.checks`: argument and shape validation, done once before a run starts;
- :mod:`.assemble`: the :class:`~jaxabc.results.ABCResult` from a finished run;
- :mod:`.fused`, :mod:`.fused_records`: the whole loop compiled with ``lax.scan`` for JAX
  simulators.

Nothing is imported here eagerly, so that ``jaxabc.driver.checks`` can be used without
compiling anything.
"""
