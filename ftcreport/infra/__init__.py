"""The host a command runs on: the cache directory, input files read safely, crash logs, process
lifetimes and stop signals, stated limits, and the rule for the names a user gives."""
