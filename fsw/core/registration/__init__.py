"""Registration of a view against the map before it is merged (docs/algorithm.md §5.1): the fit, its statistics
and the chain of registered stations."""
