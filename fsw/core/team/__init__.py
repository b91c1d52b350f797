"""The team (docs/algorithm.md §8): tether statics of the Cliff-bot on the face and its task planner."""
