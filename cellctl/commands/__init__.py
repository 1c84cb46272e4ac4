"""Sub-commands of the `cellctl` command line, one module each (see cellctl.cli)."""
