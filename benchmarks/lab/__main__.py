"""``python -m benchmarks.lab``: the command line of benchmarks/lab/command.py."""

from benchmarks.lab.command import main

main()
