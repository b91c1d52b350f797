"""One module per `safer-hil` subcommand: HELP, add_arguments(parser), run(args) -> int."""
