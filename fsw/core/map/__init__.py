"""The 2.5D elevation map (docs/algorithm.md §1, §1.1, §1.2): fusion of measured points, which view placed each
cell, and the checkpoint format."""
