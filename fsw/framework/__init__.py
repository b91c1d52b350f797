"""The framework: the vocabulary every flight component speaks (F Prime's ``Fw``).

Task, telemetry channels, events, commands, the software bus, slack jobs, clocks, the
schedule table and the typed parameter loader. It imports nothing else of the project, so
every layer above (core, protocols, drivers, tasks, executive) may import it.
"""
