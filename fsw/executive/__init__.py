"""The cyclic executive: clock, rate groups, slack jobs, health, telemetry, commands."""
