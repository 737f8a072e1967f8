"""The algorithms of ``agents``, one line each: the module that declares the algorithm's ``ALGO``
(its ``agents.registry.Algo``) and config type beside its code. The order here is the order of
``agents.ALGOS``."""

from agents.registry import register_module

register_module("agents.controllers.spgd")
register_module("agents.controllers.physics_informed")
register_module("agents.learners.brax.ppo")
register_module("agents.learners.brax.sac")
register_module("agents.learners.offpolicy.td3")
register_module("agents.learners.offpolicy.droq")
