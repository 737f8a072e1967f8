"""``python -m agents.train --algo ...``: the training command line (``agents.cli``).

Only runs as a program: ``agents.train`` is the function ``agents.train(algo, env_config, ...)``,
which importing a module of that name would hide.
"""

if __name__ != "__main__":
    raise ImportError("agents.train is the function agents.train(algo, env_config, ...); the module agents/train.py "
                      "only runs as `python -m agents.train` (its code is agents.cli)")

import sys

from agents.cli import main

sys.exit(0 if main() else 1)
