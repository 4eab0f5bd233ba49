"""CLI sub-commands; each module: NAME, HELP, add_arguments(parser), run(args) -> exit code."""
