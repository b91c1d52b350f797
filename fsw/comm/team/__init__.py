"""The team\x27s CAN frames and the relative-localization packets (docs/team.md)."""
