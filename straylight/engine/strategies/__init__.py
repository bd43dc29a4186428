"""The engine's variance-reduction strategies, one module each (docs/engine.md, "Strategies").

:mod:`.base` is the shape every strategy has (:class:`~.base.Strategy`: its declaration and its hooks),
:mod:`.registry` the ordered list :data:`~.registry.STRATEGIES` that the plan, ``trace()`` and the walk
loop over. A new estimator is one module here, one line in the registry and one row in
tests/straylight/test_engine_contract.py.
"""
