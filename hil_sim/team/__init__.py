"""The team on the bench: the Cliff-bot rig, the team mission, the team\x27s truth (docs/team.md)."""
