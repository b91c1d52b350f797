"""The Cliff-bot's flight tasks (agent kind ``cliffbot``; docs/team.md, "The Cliff-bot's topology")."""
