"""The paper's parameter studies: typed options in; a result with rows, ``to_json()``, ``report()`` and ``plot(ax)`` out."""
