"""Adapters of the OPS environment to other APIs: Gymnasium, Brax, gymnax."""
