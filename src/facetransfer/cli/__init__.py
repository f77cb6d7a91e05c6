"""Command-line interface: thin subcommands, one library call each (see :mod:`.main`)."""
