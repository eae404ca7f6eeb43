"""The ``roadbev`` command line, on top of the runtime and the lab (one module per command)."""
