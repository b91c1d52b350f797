"""Next-view selection (docs/algorithm.md §3, §7): visibility, expected information, the interest function,
motion cost, the utility and the five mapping methods."""
