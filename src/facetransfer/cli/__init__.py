"""Command-line interface: one module per subcommand group registering its parsers, the options
checked and the library called; errors said in one line (see :mod:`.main`)."""
