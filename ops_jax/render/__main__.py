"""``python -m ops_jax.render``: the objective landscape as a PNG (``ops_jax.render.main``)."""

from ops_jax.cli.parser import run
from ops_jax.render._cli import main

run("python -m ops_jax.render", main)
