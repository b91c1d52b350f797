"""Ground tools: MAVLink listener, command sender, log plots."""
