"""The drivers behind :func:`jaxabc.run`.

- :mod:`.options`: :class:`~.options.RunOptions`, every entry point's run options, validated once;
- :mod:`.checks`: argument and shape validation, done once before a run starts;
- :mod:`.calibrate`: one calibration: the problem prepared, the algorithm built, the driver chosen;
- :mod:`.host`: the host loop, for every algorithm and executor;
- :mod:`.fused`, :mod:`.fused_records`: the whole loop compiled with ``lax.scan`` for JAX
  simulators;
- :mod:`.context`: the problem, the compiled algorithm, the distance function, the simulation
  recorder;
- :mod:`.assemble`: the :class:`~jaxabc.results.ABCResult` of a finished host run.

Nothing is imported here eagerly, so that ``jaxabc.driver.checks`` can be used without
compiling anything.
"""
