"""The plumbing of the project's command-line programs: the argument parser, the missing-extra
messages, progress reporting and how a process starts JAX."""
