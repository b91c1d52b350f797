"""Map distribution (docs/algorithm.md §6): the quadtree of interest regions, its predictive coding and the
versioned container."""
