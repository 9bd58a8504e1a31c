"""One module per ``wearfit`` subcommand (argument parsing and I/O only)."""
