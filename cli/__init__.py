"""The ``vibrissa`` command line: mechanics commands, the launcher, bag and topic tools."""
