"""One module per `walkcap` subcommand: HELP, add_arguments(parser), run(args, config)."""
