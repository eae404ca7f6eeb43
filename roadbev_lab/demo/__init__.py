"""``roadbev demo``: render a drive, run it offline and through the node, and report."""
